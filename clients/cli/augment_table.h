/* Tables for gazesplat augment's label and target files: CSV with a header
 * row, or JSON Lines of flat objects (strings, numbers, null). Cells are
 * kept as text; empty cells and JSON nulls are NULL. */
#ifndef GS_CLI_AUGMENT_TABLE_H
#define GS_CLI_AUGMENT_TABLE_H

#include <stddef.h>

typedef struct aug_table {
    int ncols;
    char **cols;     /* column names, in first-seen order */
    size_t nrows;
    char ***cells;   /* cells[row][col], NULL when empty or null */
    size_t *line;    /* the file's line number (1-based) of each row */
} aug_table;

/* Reads path: JSON Lines when its first non-blank byte is '{', else CSV.
 * Blank lines are skipped. On failure msg says where ("line N: ...") and
 * -1 is returned with *t empty. */
int aug_table_read(const char *path, aug_table *t, char *msg, size_t cap);
/* Parses a whole file's text (text[len]); as aug_table_read. */
int aug_table_parse(const char *text, size_t len, aug_table *t, char *msg, size_t cap);
/* The column's index, -1 when absent. */
int aug_table_col(const aug_table *t, const char *name);
void aug_table_free(aug_table *t);

#endif
