/* Model files: save -> load round trip (every tensor, the configuration),
 * and refusal of truncated, corrupt and inconsistent files; the optional
 * config.fit_code_prior and config.fit_code_rate: kept exactly, 0 when
 * absent (older files), refused outside [0, 10] or unparsable. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/safetensors.h"
#include "gs_test.h"
#include "model_test_util.h"

static char path[256];

static char *find(uint8_t *buf, size_t len, const char *needle)
{
    size_t n = strlen(needle);
    for (size_t i = 0; i + n <= len; i++)
        if (memcmp(buf + i, needle, n) == 0)
            return (char *)buf + i;
    return NULL;
}

static int load_bytes(const uint8_t *buf, size_t len, int *code)
{
    char p2[300];
    snprintf(p2, sizeof p2, "%s.bad", path);
    FILE *f = fopen(p2, "wb");
    fwrite(buf, 1, len, f);
    fclose(f);
    gs_model *m = NULL;
    gs_error err = {0, ""};
    *code = gs_model_load(p2, &m, &err);
    if (*code == GS_OK)
        gs_model_destroy(m);
    else if (!err.msg[0])
        return 0; /* every refusal must say why */
    unlink(p2);
    return 1;
}

/* The file at path again with its metadata key `key` set to value (or
 * left out, value NULL): the bytes in *out (free them). */
static int with_meta(const char *key, const char *value, uint8_t **out,
                     size_t *len)
{
    gs_error err = {0, ""};
    gs_st_file *sf = NULL;
    if (gs_st_open(path, NULL, &sf, &err) != GS_OK)
        return 0;
    gs_st_writer *w = gs_st_writer_create();
    int rc = w ? 0 : -1;
    for (int i = 0; !rc && i < gs_st_meta_count(sf); i++) {
        const char *k, *v;
        gs_st_meta_at(sf, i, &k, &v);
        if (strcmp(k, key) != 0)
            rc = gs_st_writer_meta(w, k, v);
    }
    if (!rc && value)
        rc = gs_st_writer_meta(w, key, value);
    for (int i = 0; !rc && i < gs_st_count(sf); i++) {
        const gs_st_tensor *t = gs_st_at(sf, i);
        rc = gs_st_writer_add(w, t->name, t->dtype, t->ndim, t->shape, t->data);
    }
    if (!rc)
        rc = gs_st_writer_to_mem(w, out, len, &err);
    gs_st_writer_destroy(w);
    gs_st_close(sf);
    return rc == 0;
}

/* Loads bytes; returns the code, and in *value the fit setting it named
 * (rate 1: config.fit_code_rate, else config.fit_code_prior), or -1. */
static int load_setting(const uint8_t *buf, size_t len, int rate, double *value,
                        char *msg, size_t cap)
{
    gs_model *m = NULL;
    gs_error err = {0, ""};
    int code = gs_model_load_mem(buf, len, &m, &err);
    *value = -1;
    if (code == GS_OK) {
        gs_model_info info;
        gs_model_get_info(m, &info);
        *value = rate ? info.fit_code_rate : info.fit_code_prior;
        gs_model_destroy(m);
    }
    snprintf(msg, cap, "%s", err.msg);
    return code;
}

static void fit_prior_key(gs_model *m)
{
    gs_error err = {0, ""};
    const double w = (double)3e-4f; /* as `--fit-code-prior 0.0003` reads */
    CHECK(m->cfg.fit_code_prior == 0);
    CHECK(gs_model_set_fit_code_prior(m, w, &err) == GS_OK);
    CHECK(gs_model_save(m, path, &err) == GS_OK);
    gs_model *l = NULL;
    CHECK_MSG(gs_model_load(path, &l, &err) == GS_OK, "%s", err.msg);
    CHECK(l && l->cfg.fit_code_prior == w); /* every bit (%.17g) */
    CHECK(l && memcmp(&l->cfg, &m->cfg, sizeof m->cfg) == 0);
    gs_model_destroy(l);
    /* the setter refuses what the file would, and keeps the value */
    const double bad[] = {-1.0, -1e-9, 10.5, NAN, INFINITY};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        CHECK(gs_model_set_fit_code_prior(m, bad[k], &err) == GS_ERR_ARG);
        CHECK(strstr(err.msg, "code prior") != NULL);
    }
    CHECK(gs_model_set_fit_code_prior(NULL, 0.1, &err) == GS_ERR_ARG);
    CHECK(m->cfg.fit_code_prior == w);

    struct { const char *value; int code; double prior; } cases[] = {
        {NULL, GS_OK, 0.0},      /* a file from before the key: none */
        {"0", GS_OK, 0.0},       {"10", GS_OK, 10.0},
        {"0.00030000001424923539", GS_OK, w},
        {"-0.5", GS_ERR_FORMAT, -1}, {"10.5", GS_ERR_FORMAT, -1},
        {"nan", GS_ERR_FORMAT, -1},  {"inf", GS_ERR_FORMAT, -1},
        {"1e", GS_ERR_FORMAT, -1},   {"", GS_ERR_FORMAT, -1},
        {"0.1x", GS_ERR_FORMAT, -1}, {"1e400", GS_ERR_FORMAT, -1},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        uint8_t *b = NULL;
        size_t n = 0;
        CHECK(with_meta("config.fit_code_prior", cases[k].value, &b, &n));
        double prior = -2;
        char msg[256] = "";
        int code = b ? load_setting(b, n, 0, &prior, msg, sizeof msg) : -99;
        CHECK_MSG(code == cases[k].code && prior == cases[k].prior,
                  "fit_code_prior '%s': code %d, prior %g", cases[k].value ? cases[k].value : "(absent)",
                  code, prior);
        if (cases[k].code != GS_OK)
            CHECK_MSG(strstr(msg, "fit_code_prior") != NULL, "'%s': %s",
                      cases[k].value, msg);
        free(b);
    }
    CHECK(gs_model_set_fit_code_prior(m, 0, &err) == GS_OK);
}

static void fit_rate_key(gs_model *m)
{
    gs_error err = {0, ""};
    const double r = 0.24; /* as `--fit-code-rate 0.24` reads (strtod) */
    CHECK(m->cfg.fit_code_rate == 0);
    CHECK(gs_model_set_fit_code_rate(m, r, &err) == GS_OK);
    CHECK(gs_model_save(m, path, &err) == GS_OK);
    gs_model *l = NULL;
    CHECK_MSG(gs_model_load(path, &l, &err) == GS_OK, "%s", err.msg);
    CHECK(l && l->cfg.fit_code_rate == r); /* every bit (%.17g) */
    CHECK(l && memcmp(&l->cfg, &m->cfg, sizeof m->cfg) == 0);
    gs_model_destroy(l);
    const double bad[] = {-1.0, -1e-9, 10.5, NAN, INFINITY};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        CHECK(gs_model_set_fit_code_rate(m, bad[k], &err) == GS_ERR_ARG);
        CHECK(strstr(err.msg, "code rate") != NULL);
    }
    CHECK(gs_model_set_fit_code_rate(NULL, 0.1, &err) == GS_ERR_ARG);
    CHECK(m->cfg.fit_code_rate == r);

    struct { const char *value; int code; double rate; } cases[] = {
        {NULL, GS_OK, 0.0},      /* a file from before the key: none */
        {"0", GS_OK, 0.0},       {"10", GS_OK, 10.0},
        {"0.23999999999999999", GS_OK, r},
        {"-0.5", GS_ERR_FORMAT, -1}, {"10.5", GS_ERR_FORMAT, -1},
        {"nan", GS_ERR_FORMAT, -1},  {"inf", GS_ERR_FORMAT, -1},
        {"1e", GS_ERR_FORMAT, -1},   {"", GS_ERR_FORMAT, -1},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        uint8_t *b = NULL;
        size_t n = 0;
        CHECK(with_meta("config.fit_code_rate", cases[k].value, &b, &n));
        double rate = -2;
        char msg[256] = "";
        int code = b ? load_setting(b, n, 1, &rate, msg, sizeof msg) : -99;
        CHECK_MSG(code == cases[k].code && rate == cases[k].rate,
                  "fit_code_rate '%s': code %d, rate %g",
                  cases[k].value ? cases[k].value : "(absent)", code, rate);
        if (cases[k].code != GS_OK)
            CHECK_MSG(strstr(msg, "fit_code_rate") != NULL, "'%s': %s",
                      cases[k].value, msg);
        free(b);
    }
    CHECK(gs_model_set_fit_code_rate(m, 0, &err) == GS_OK);
}

int main(void)
{
    snprintf(path, sizeof path, "test_model_file_%d.safetensors", (int)getpid());
    gs_model *m = tiny_model(2, 3);
    CHECK(m != NULL);
    gs_error err = {0, ""};
    CHECK(gs_model_save(m, path, &err) == GS_OK);
    gs_model *l = NULL;
    CHECK_MSG(gs_model_load(path, &l, &err) == GS_OK, "%s", err.msg);
    CHECK(l->nparams == m->nparams);
    CHECK(memcmp(&l->cfg, &m->cfg, sizeof m->cfg) == 0);
    int same = 1;
    for (int i = 0; i < m->ntensors; i++)
        same &= memcmp(l->params + m->t[i].offset, m->params + m->t[i].offset,
                       m->t[i].count * sizeof(float)) == 0;
    CHECK_MSG(same, "a tensor differs after the round trip");
    gs_model_destroy(l);

    FILE *f = fopen(path, "rb");
    fseek(f, 0, SEEK_END);
    size_t len = (size_t)ftell(f);
    fseek(f, 0, SEEK_SET);
    uint8_t *buf = malloc(len);
    CHECK(fread(buf, 1, len, f) == len);
    fclose(f);
    int code;
    /* truncations */
    size_t cuts[] = {0, 7, 8, 100, len / 2, len - 1};
    for (size_t i = 0; i < sizeof cuts / sizeof cuts[0]; i++) {
        CHECK(load_bytes(buf, cuts[i], &code));
        CHECK_MSG(code == GS_ERR_FORMAT || code == GS_ERR_IO,
                  "cut at %zu: code %d", cuts[i], code);
    }
    /* a flipped byte in the header's config */
    uint8_t *bad = malloc(len);
    memcpy(bad, buf, len);
    char *hit = find(bad, len, "\"config.hidden\":\"16\"");
    CHECK(hit != NULL);
    if (hit) {
        hit[18] = '9'; /* hidden 96: shapes no longer match */
        CHECK(load_bytes(bad, len, &code));
        CHECK_MSG(code == GS_ERR_FORMAT, "bad config: code %d", code);
    }
    memcpy(bad, buf, len);
    hit = find(bad, len, "gazesplat-model");
    CHECK(hit != NULL);
    if (hit) {
        hit[0] = 'G';
        CHECK(load_bytes(bad, len, &code));
        CHECK_MSG(code == GS_ERR_FORMAT, "bad format name: code %d", code);
    }
    /* a NaN parameter */
    memcpy(bad, buf, len);
    uint32_t nan = 0x7fc00000u;
    memcpy(bad + len - 4, &nan, 4);
    CHECK(load_bytes(bad, len, &code));
    CHECK_MSG(code == GS_ERR_NONFINITE, "NaN tensor: code %d", code);
    /* a missing tensor: rewrite without one */
    gs_st_file *sf = NULL;
    CHECK(gs_st_open(path, NULL, &sf, &err) == GS_OK);
    gs_st_writer *w = gs_st_writer_create();
    for (int i = 0; i < gs_st_meta_count(sf); i++) {
        const char *k, *v;
        gs_st_meta_at(sf, i, &k, &v);
        gs_st_writer_meta(w, k, v);
    }
    for (int i = 0; i < gs_st_count(sf); i++) {
        const gs_st_tensor *t = gs_st_at(sf, i);
        if (strcmp(t->name, "eye.centre") == 0)
            continue;
        gs_st_writer_add(w, t->name, t->dtype, t->ndim, t->shape, t->data);
    }
    uint8_t *mb = NULL;
    size_t ml = 0;
    CHECK(gs_st_writer_to_mem(w, &mb, &ml, &err) == GS_OK);
    CHECK(load_bytes(mb, ml, &code));
    CHECK_MSG(code == GS_ERR_FORMAT, "missing tensor: code %d", code);
    free(mb);
    gs_st_writer_destroy(w);
    gs_st_close(sf);
    free(bad);
    free(buf);
    fit_prior_key(m);
    fit_rate_key(m);
    unlink(path);
    gs_model_destroy(m);
    GS_TEST_END();
}
