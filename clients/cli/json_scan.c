/* One JSON object per line: a recursive-descent validator that records
 * the top-level members (json_scan.h). */
#include "json_scan.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_DEPTH 32

typedef struct scan {
    const char *s, *e, *p;
    char *msg;
    size_t cap;
    int failed;
} scan;

static int fail(scan *c, const char *what)
{
    if (!c->failed)
        snprintf(c->msg, c->cap, "column %zu: %s", (size_t)(c->p - c->s) + 1, what);
    c->failed = 1;
    return -1;
}

static void skip_ws(scan *c)
{
    while (c->p < c->e && (*c->p == ' ' || *c->p == '\t' || *c->p == '\r' || *c->p == '\n'))
        c->p++;
}

static int is_hex(char ch)
{
    return (ch >= '0' && ch <= '9') || (ch >= 'a' && ch <= 'f') || (ch >= 'A' && ch <= 'F');
}

/* At the opening quote; leaves p after the closing one. */
static int string(scan *c)
{
    c->p++;
    while (c->p < c->e && *c->p != '"') {
        unsigned char ch = (unsigned char)*c->p;
        if (ch < 0x20)
            return fail(c, "control character in a string");
        if (ch == '\\') {
            c->p++;
            if (c->p >= c->e)
                break;
            if (*c->p == 'u') {
                for (int i = 1; i <= 4; i++)
                    if (c->p + i >= c->e || !is_hex(c->p[i]))
                        return fail(c, "bad \\u escape");
                c->p += 4;
            } else if (!strchr("\"\\/bfnrt", *c->p)) {
                return fail(c, "bad escape in a string");
            }
        }
        c->p++;
    }
    if (c->p >= c->e)
        return fail(c, "unterminated string");
    c->p++;
    return 0;
}

static int number(scan *c)
{
    const char *q = c->p;
    if (q < c->e && *q == '-')
        q++;
    if (q >= c->e || !(*q >= '0' && *q <= '9'))
        return fail(c, "expected a value");
    if (*q == '0')
        q++;
    else
        while (q < c->e && *q >= '0' && *q <= '9')
            q++;
    if (q < c->e && *q == '.') {
        q++;
        if (q >= c->e || !(*q >= '0' && *q <= '9'))
            return fail(c, "bad number");
        while (q < c->e && *q >= '0' && *q <= '9')
            q++;
    }
    if (q < c->e && (*q == 'e' || *q == 'E')) {
        q++;
        if (q < c->e && (*q == '+' || *q == '-'))
            q++;
        if (q >= c->e || !(*q >= '0' && *q <= '9'))
            return fail(c, "bad number");
        while (q < c->e && *q >= '0' && *q <= '9')
            q++;
    }
    c->p = q;
    return 0;
}

static int value(scan *c, int depth, int *kind);

static int literal(scan *c, const char *word)
{
    size_t n = strlen(word);
    if ((size_t)(c->e - c->p) < n || memcmp(c->p, word, n) != 0)
        return fail(c, "expected a value");
    c->p += n;
    return 0;
}

/* Array or object at its opening bracket. */
static int container(scan *c, int depth, int object)
{
    if (depth >= MAX_DEPTH)
        return fail(c, "nested too deeply");
    char close = object ? '}' : ']';
    c->p++;
    skip_ws(c);
    if (c->p < c->e && *c->p == close) {
        c->p++;
        return 0;
    }
    for (;;) {
        int kind;
        skip_ws(c);
        if (object) {
            if (c->p >= c->e || *c->p != '"')
                return fail(c, "expected a member name");
            if (string(c))
                return -1;
            skip_ws(c);
            if (c->p >= c->e || *c->p != ':')
                return fail(c, "expected ':'");
            c->p++;
            skip_ws(c);
        }
        if (value(c, depth + 1, &kind))
            return -1;
        skip_ws(c);
        if (c->p < c->e && *c->p == ',') {
            c->p++;
            continue;
        }
        if (c->p < c->e && *c->p == close) {
            c->p++;
            return 0;
        }
        return fail(c, object ? "expected ',' or '}'" : "expected ',' or ']'");
    }
}

static int value(scan *c, int depth, int *kind)
{
    if (c->p >= c->e)
        return fail(c, "expected a value");
    switch (*c->p) {
    case '"':
        *kind = JS_STRING;
        return string(c);
    case '{':
        *kind = JS_OBJECT;
        return container(c, depth, 1);
    case '[':
        *kind = JS_ARRAY;
        return container(c, depth, 0);
    case 'n':
        *kind = JS_NULL;
        return literal(c, "null");
    case 't':
        *kind = JS_BOOL;
        return literal(c, "true");
    case 'f':
        *kind = JS_BOOL;
        return literal(c, "false");
    default:
        *kind = JS_NUMBER;
        return number(c);
    }
}

int js_scan_object(const char *line, size_t len, js_object *o, char *msg, size_t cap)
{
    scan c = {line, line + len, line, msg, cap, 0};
    o->n = 0;
    skip_ws(&c);
    if (c.p >= c.e || *c.p != '{')
        return fail(&c, "expected '{' (one JSON object per line)");
    c.p++;
    skip_ws(&c);
    if (c.p < c.e && *c.p == '}') {
        c.p++;
    } else {
        for (;;) {
            skip_ws(&c);
            if (c.p >= c.e || *c.p != '"')
                return fail(&c, "expected a member name");
            const char *k = c.p + 1;
            if (string(&c))
                return -1;
            size_t klen = (size_t)(c.p - 1 - k);
            skip_ws(&c);
            if (c.p >= c.e || *c.p != ':')
                return fail(&c, "expected ':'");
            c.p++;
            skip_ws(&c);
            const char *v = c.p;
            int kind;
            if (value(&c, 1, &kind))
                return -1;
            if (o->n == JS_MAX_MEMBERS)
                return fail(&c, "too many members");
            o->m[o->n].key = k;
            o->m[o->n].key_len = klen;
            o->m[o->n].v.kind = kind;
            o->m[o->n].v.p = kind == JS_STRING ? v + 1 : v;
            o->m[o->n].v.len = (size_t)(c.p - v) - (kind == JS_STRING ? 2 : 0);
            o->n++;
            skip_ws(&c);
            if (c.p < c.e && *c.p == ',') {
                c.p++;
                continue;
            }
            if (c.p < c.e && *c.p == '}') {
                c.p++;
                break;
            }
            return fail(&c, "expected ',' or '}'");
        }
    }
    skip_ws(&c);
    if (c.p != c.e)
        return fail(&c, "text after the object");
    return 0;
}

const js_value *js_get(const js_object *o, const char *key)
{
    size_t n = strlen(key);
    for (int i = o->n - 1; i >= 0; i--)
        if (o->m[i].key_len == n && memcmp(o->m[i].key, key, n) == 0)
            return &o->m[i].v;
    return NULL;
}

int js_get_number(const js_object *o, const char *key, double *out, int *kind_out)
{
    const js_value *v = js_get(o, key);
    if (kind_out)
        *kind_out = v ? v->kind : JS_NONE;
    if (!v || v->kind != JS_NUMBER)
        return -1;
    char buf[64];
    if (v->len >= sizeof buf)
        return -1;
    memcpy(buf, v->p, v->len);
    buf[v->len] = '\0';
    *out = strtod(buf, NULL);
    return isfinite(*out) ? 0 : -1;
}

int js_get_string(const js_object *o, const char *key, char *buf, size_t cap)
{
    const js_value *v = js_get(o, key);
    if (!v || v->kind != JS_STRING || cap == 0)
        return -1;
    size_t n = 0;
    for (size_t i = 0; i < v->len; i++) {
        char ch = v->p[i];
        if (ch == '\\' && i + 1 < v->len) {
            char e = v->p[++i];
            static const char from[] = "\"\\/bfnrt", to[] = "\"\\/\b\f\n\r\t";
            const char *f = strchr(from, e);
            if (e == 'u' && i + 4 < v->len) {
                char hex[5] = {v->p[i + 1], v->p[i + 2], v->p[i + 3], v->p[i + 4], 0};
                unsigned u = (unsigned)strtoul(hex, NULL, 16);
                if (u == 0 || u > 0x7f)
                    return -1;
                ch = (char)u;
                i += 4;
            } else if (f) {
                ch = to[f - from];
            }
        }
        if (n + 1 >= cap)
            return -1;
        buf[n++] = ch;
    }
    buf[n] = '\0';
    return 0;
}
