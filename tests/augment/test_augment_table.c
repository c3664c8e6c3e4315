/* augment_table: CSV and JSON Lines, the errors' line numbers. */
#include <string.h>

#include "augment_table.h"
#include "gs_test.h"

static int parse(const char *text, aug_table *t, char *msg)
{
    return aug_table_parse(text, strlen(text), t, msg, 256);
}

static const char *cell(const aug_table *t, size_t r, const char *col)
{
    int c = aug_table_col(t, col);
    return c < 0 ? "(no column)" : t->cells[r][c] ? t->cells[r][c] : "(null)";
}

int main(void)
{
    aug_table t;
    char msg[256];
    /* CSV: header, quotes, blanks, CRLF, empty cells. */
    CHECK(parse("file, gaze_pitch_deg ,subject\r\n\r\na.png,1.5,\"x, \"\"y\"\"\"\nb.png,,s\n",
                &t, msg) == 0);
    CHECK_EQ_INT(t.ncols, 3);
    CHECK_EQ_INT(t.nrows, 2);
    CHECK(strcmp(cell(&t, 0, "gaze_pitch_deg"), "1.5") == 0);
    CHECK(strcmp(cell(&t, 0, "subject"), "x, \"y\"") == 0);
    CHECK(strcmp(cell(&t, 1, "gaze_pitch_deg"), "(null)") == 0);
    CHECK_EQ_INT(t.line[0], 3);
    CHECK_EQ_INT(t.line[1], 4);
    aug_table_free(&t);
    /* CSV errors name the line. */
    CHECK(parse("a,b\n1,2\n1,2,3\n", &t, msg) != 0 && strstr(msg, "line 3"));
    CHECK(parse("a,b\n1\n", &t, msg) != 0 && strstr(msg, "line 2"));
    CHECK(parse("a,a\n", &t, msg) != 0 && strstr(msg, "twice"));
    CHECK(parse("a,b\n\"1,2\n", &t, msg) != 0 && strstr(msg, "malformed"));
    CHECK(parse("", &t, msg) != 0);
    /* JSONL: keys in first-seen order, null and "" as absent, escapes. */
    CHECK(parse("{\"file\": \"a\\\"b.png\", \"gaze_pitch_deg\": -2e1}\n\n"
                "{\"gaze_yaw_deg\": 3, \"file\": \"c.png\", \"subject\": null}\n", &t, msg) == 0);
    CHECK_EQ_INT(t.ncols, 4);
    CHECK_EQ_INT(t.nrows, 2);
    CHECK(strcmp(cell(&t, 0, "file"), "a\"b.png") == 0);
    CHECK(strcmp(cell(&t, 0, "gaze_pitch_deg"), "-2e1") == 0);
    CHECK(strcmp(cell(&t, 0, "gaze_yaw_deg"), "(null)") == 0);
    CHECK(strcmp(cell(&t, 1, "gaze_yaw_deg"), "3") == 0);
    CHECK(strcmp(cell(&t, 1, "subject"), "(null)") == 0);
    CHECK_EQ_INT(t.line[1], 3);
    aug_table_free(&t);
    CHECK(parse("{\"a\": 1}\n{\"a\": [1]}\n", &t, msg) != 0 && strstr(msg, "line 2"));
    CHECK(parse("{\"a\": 1, \"a\": 2}\n", &t, msg) != 0 && strstr(msg, "twice"));
    CHECK(parse("{\"a\": 1}\nnot json\n", &t, msg) != 0 && strstr(msg, "line 2"));
    CHECK(parse("{\"a\": 1} x\n", &t, msg) != 0 && strstr(msg, "after the object"));
    CHECK(parse("{\"a\": \"unterminated}\n", &t, msg) != 0);
    CHECK(aug_table_parse("a,b\n\0\n", 6, &t, msg, sizeof msg) != 0);
    GS_TEST_END();
}
