/* CSV and JSON Lines tables (augment_table.h). */
#define _POSIX_C_SOURCE 200809L
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "augment_table.h"
#include "cli.h"

#define MAX_TABLE_BYTES ((size_t)1 << 30)
#define MAX_COLS 64
#define MAX_CELL 4096

static int fail(char *msg, size_t cap, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static int fail(char *msg, size_t cap, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, cap, fmt, ap);
    va_end(ap);
    return -1;
}

int aug_table_col(const aug_table *t, const char *name)
{
    for (int i = 0; i < t->ncols; i++)
        if (strcmp(t->cols[i], name) == 0)
            return i;
    return -1;
}

void aug_table_free(aug_table *t)
{
    for (size_t r = 0; r < t->nrows; r++) {
        for (int c = 0; c < t->ncols && t->cells[r]; c++)
            free(t->cells[r][c]);
        free(t->cells[r]);
    }
    for (int c = 0; c < t->ncols; c++)
        free(t->cols[c]);
    free(t->cols);
    free(t->cells);
    free(t->line);
    memset(t, 0, sizeof *t);
}

static int add_col(aug_table *t, const char *name)
{
    if (t->ncols == MAX_COLS)
        return -1;
    char **c = realloc(t->cols, sizeof *c * (size_t)(t->ncols + 1));
    if (!c)
        return -1;
    t->cols = c;
    if (!(c[t->ncols] = strdup(name)))
        return -1;
    /* Earlier rows get NULL in the new column (cells are MAX_COLS wide). */
    return t->ncols++;
}

static char **add_row(aug_table *t, size_t line)
{
    char ***cells = realloc(t->cells, sizeof *cells * (t->nrows + 1));
    if (!cells)
        return NULL;
    t->cells = cells;
    size_t *ln = realloc(t->line, sizeof *ln * (t->nrows + 1));
    if (!ln)
        return NULL;
    t->line = ln;
    char **row = calloc(MAX_COLS, sizeof *row);
    if (!row)
        return NULL;
    cells[t->nrows] = row;
    ln[t->nrows] = line;
    t->nrows++;
    return row;
}

/* ---- CSV ---- */

/* One field starting at *p (within the line [*p, end)); returns its
 * length in buf or -1. Advances *p past the field and its comma. */
static int csv_field(const char **p, const char *end, char *buf, int *more)
{
    const char *s = *p;
    size_t n = 0;
    while (s < end && (*s == ' ' || *s == '\t'))
        s++;
    if (s < end && *s == '"') {
        s++;
        for (;;) {
            if (s >= end)
                return -1; /* unterminated quote */
            if (*s == '"') {
                if (s + 1 < end && s[1] == '"') {
                    s += 2;
                    if (n + 1 >= MAX_CELL)
                        return -1;
                    buf[n++] = '"';
                    continue;
                }
                s++;
                break;
            }
            if (n + 1 >= MAX_CELL)
                return -1;
            buf[n++] = *s++;
        }
        while (s < end && (*s == ' ' || *s == '\t'))
            s++;
        if (s < end && *s != ',')
            return -1;
    } else {
        while (s < end && *s != ',') {
            if (n + 1 >= MAX_CELL)
                return -1;
            buf[n++] = *s++;
        }
        while (n > 0 && (buf[n - 1] == ' ' || buf[n - 1] == '\t'))
            n--;
    }
    buf[n] = '\0';
    *more = s < end && *s == ',';
    *p = s < end ? s + 1 : s;
    return (int)n;
}

static int parse_csv(const char *text, size_t len, aug_table *t, char *msg, size_t cap)
{
    const char *p = text, *end = text + len;
    size_t line = 0;
    char *buf = malloc(MAX_CELL);
    int header = 1, rc = 0;
    if (!buf)
        return fail(msg, cap, "out of memory");
    while (p < end && rc == 0) {
        const char *e = memchr(p, '\n', (size_t)(end - p));
        const char *next = e ? e + 1 : end;
        if (!e)
            e = end;
        line++;
        if (e > p && e[-1] == '\r')
            e--;
        const char *q = p;
        while (q < e && (*q == ' ' || *q == '\t'))
            q++;
        if (q == e) { /* blank */
            p = next;
            continue;
        }
        char **row = header ? NULL : add_row(t, line);
        if (!header && !row) {
            rc = fail(msg, cap, "out of memory");
            break;
        }
        int col = 0, more = 1;
        q = p;
        while (more && rc == 0) {
            int n = csv_field(&q, e, buf, &more);
            if (n < 0)
                rc = fail(msg, cap, "line %zu: malformed field %d (quotes, or over %d bytes)", line,
                          col + 1, MAX_CELL - 1);
            else if (header) {
                if (n == 0)
                    rc = fail(msg, cap, "line %zu: empty column name %d", line, col + 1);
                else if (aug_table_col(t, buf) >= 0)
                    rc = fail(msg, cap, "line %zu: column '%s' twice", line, buf);
                else if (add_col(t, buf) < 0)
                    rc = fail(msg, cap, "line %zu: too many columns (over %d)", line, MAX_COLS);
            } else if (col >= t->ncols)
                rc = fail(msg, cap, "line %zu: more fields than the header's %d columns", line,
                          t->ncols);
            else if (n > 0 && !(row[col] = strdup(buf)))
                rc = fail(msg, cap, "out of memory");
            col++;
        }
        if (rc == 0 && !header && col != t->ncols)
            rc = fail(msg, cap, "line %zu: %d fields; the header has %d columns", line, col,
                      t->ncols);
        header = 0;
        p = next;
    }
    free(buf);
    if (rc == 0 && header)
        rc = fail(msg, cap, "empty: want a header row");
    return rc;
}

/* ---- JSON Lines ---- */

static void skip_ws(const char **p, const char *e)
{
    while (*p < e && (**p == ' ' || **p == '\t' || **p == '\r'))
        (*p)++;
}

/* A JSON string at *p (on the quote) into buf (ASCII escapes and \uXXXX
 * below 0x80 only; other bytes copied as they are). */
static int json_string(const char **p, const char *e, char *buf)
{
    const char *s = *p + 1;
    size_t n = 0;
    while (s < e && *s != '"') {
        char c = *s++;
        if (c == '\\') {
            if (s >= e)
                return -1;
            char x = *s++;
            switch (x) {
            case '"': case '\\': case '/': c = x; break;
            case 'n': c = '\n'; break;
            case 't': c = '\t'; break;
            case 'r': c = '\r'; break;
            case 'b': c = '\b'; break;
            case 'f': c = '\f'; break;
            case 'u': {
                unsigned v = 0;
                for (int i = 0; i < 4; i++) {
                    if (s >= e)
                        return -1;
                    char h = *s++;
                    v = v * 16 + (unsigned)(h >= '0' && h <= '9'   ? h - '0'
                                            : h >= 'a' && h <= 'f' ? h - 'a' + 10
                                            : h >= 'A' && h <= 'F' ? h - 'A' + 10
                                                                   : 99);
                }
                if (v >= 0x80 || v == 0)
                    return -1;
                c = (char)v;
                break;
            }
            default:
                return -1;
            }
        } else if ((unsigned char)c < 0x20)
            return -1;
        if (n + 1 >= MAX_CELL)
            return -1;
        buf[n++] = c;
    }
    if (s >= e)
        return -1;
    buf[n] = '\0';
    *p = s + 1;
    return (int)n;
}

/* A scalar that is not a string: a number, true, false or null (as text). */
static int json_bare(const char **p, const char *e, char *buf)
{
    const char *s = *p;
    size_t n = 0;
    while (s < e && *s != ',' && *s != '}' && *s != ' ' && *s != '\t' && *s != '\r') {
        if (*s == '{' || *s == '[' || *s == '"' || n + 1 >= MAX_CELL)
            return -1;
        buf[n++] = *s++;
    }
    buf[n] = '\0';
    *p = s;
    return n ? (int)n : -1;
}

static int parse_jsonl(const char *text, size_t len, aug_table *t, char *msg, size_t cap)
{
    const char *p = text, *end = text + len;
    size_t line = 0;
    char *key = malloc(MAX_CELL), *val = malloc(MAX_CELL);
    int rc = 0;
    if (!key || !val)
        rc = fail(msg, cap, "out of memory");
    while (p < end && rc == 0) {
        const char *e = memchr(p, '\n', (size_t)(end - p));
        const char *next = e ? e + 1 : end;
        if (!e)
            e = end;
        line++;
        const char *q = p;
        skip_ws(&q, e);
        if (q == e) {
            p = next;
            continue;
        }
        char **row = add_row(t, line);
        if (!row) {
            rc = fail(msg, cap, "out of memory");
            break;
        }
        if (*q != '{') {
            rc = fail(msg, cap, "line %zu: not a JSON object", line);
            break;
        }
        q++;
        skip_ws(&q, e);
        int first = 1;
        while (rc == 0) {
            if (q < e && *q == '}' && first) {
                q++;
                break;
            }
            if (q >= e || *q != '"' || json_string(&q, e, key) < 0) {
                rc = fail(msg, cap, "line %zu: want a quoted key", line);
                break;
            }
            skip_ws(&q, e);
            if (q >= e || *q != ':') {
                rc = fail(msg, cap, "line %zu: want ':' after \"%s\"", line, key);
                break;
            }
            q++;
            skip_ws(&q, e);
            int is_str = q < e && *q == '"';
            int n = is_str ? json_string(&q, e, val) : json_bare(&q, e, val);
            if (n < 0) {
                rc = fail(msg, cap, "line %zu: \"%s\": want a string, a number or null (flat "
                          "objects only)", line, key);
                break;
            }
            int c = aug_table_col(t, key);
            if (c < 0 && (c = add_col(t, key)) < 0) {
                rc = fail(msg, cap, "line %zu: too many keys (over %d)", line, MAX_COLS);
                break;
            }
            if (row[c]) {
                rc = fail(msg, cap, "line %zu: key \"%s\" twice", line, key);
                break;
            }
            if (!(is_str ? n == 0 : strcmp(val, "null") == 0) && !(row[c] = strdup(val))) {
                rc = fail(msg, cap, "out of memory");
                break;
            }
            skip_ws(&q, e);
            first = 0;
            if (q < e && *q == ',') {
                q++;
                skip_ws(&q, e);
                continue;
            }
            if (q < e && *q == '}') {
                q++;
                break;
            }
            rc = fail(msg, cap, "line %zu: want ',' or '}' after \"%s\"", line, key);
        }
        skip_ws(&q, e);
        if (rc == 0 && q != e)
            rc = fail(msg, cap, "line %zu: text after the object", line);
        p = next;
    }
    free(key);
    free(val);
    return rc;
}

int aug_table_parse(const char *text, size_t len, aug_table *t, char *msg, size_t cap)
{
    memset(t, 0, sizeof *t);
    if (memchr(text, '\0', len)) {
        snprintf(msg, cap, "binary data (a NUL byte)");
        return -1;
    }
    size_t i = 0;
    while (i < len && (text[i] == ' ' || text[i] == '\t' || text[i] == '\r' || text[i] == '\n'))
        i++;
    int rc = i < len && text[i] == '{' ? parse_jsonl(text, len, t, msg, cap)
                                       : parse_csv(text, len, t, msg, cap);
    if (rc)
        aug_table_free(t);
    return rc;
}

int aug_table_read(const char *path, aug_table *t, char *msg, size_t cap)
{
    uint8_t *buf = NULL;
    size_t len = 0;
    memset(t, 0, sizeof *t);
    if (cli_read_file(path, MAX_TABLE_BYTES, &buf, &len)) {
        snprintf(msg, cap, "cannot read (missing, empty or over 1 GiB)");
        return -1;
    }
    int rc = aug_table_parse((const char *)buf, len, t, msg, cap);
    free(buf);
    return rc;
}
