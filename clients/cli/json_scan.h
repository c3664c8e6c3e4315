/* A validating scanner for one JSON object per line (labels.jsonl): the
 * whole line is checked (RFC 8259 grammar, nesting up to 32 levels) and
 * the top-level members are found by name without building a tree. */
#ifndef GS_CLI_JSON_SCAN_H
#define GS_CLI_JSON_SCAN_H

#include <stddef.h>

enum { JS_NONE = 0, JS_NULL, JS_BOOL, JS_NUMBER, JS_STRING, JS_ARRAY, JS_OBJECT };

/* A top-level member's value: its kind and its text (for a string, the
 * body between the quotes, escapes as written). */
typedef struct js_value {
    int kind;
    const char *p;
    size_t len;
} js_value;

#define JS_MAX_MEMBERS 256

typedef struct js_object {
    int n;
    struct {
        const char *key;   /* between the quotes, escapes as written */
        size_t key_len;
        js_value v;
    } m[JS_MAX_MEMBERS];
} js_object;

/* Scans line[0..len) as one object. Returns 0, or -1 with a message
 * ("column 17: expected ':'") in msg. */
int js_scan_object(const char *line, size_t len, js_object *o, char *msg, size_t cap);

/* The member named key (the last one when repeated), or NULL. */
const js_value *js_get(const js_object *o, const char *key);

/* A number member as a double: 0, or -1 when absent, null or not a
 * number (*kind_out, when not NULL, tells which: JS_NONE, JS_NULL, ...). */
int js_get_number(const js_object *o, const char *key, double *out, int *kind_out);

/* A string member's body unescaped into buf (cap bytes, NUL-terminated;
 * \uXXXX kept only for ASCII). 0, or -1 when absent, not a string or too
 * long. */
int js_get_string(const js_object *o, const char *key, char *buf, size_t cap);

#endif
