/* The served model (model_ref.h): references, the id (a hash of the
 * file's bytes: subjects belong to one model), the loader thread, the swap
 * on the loop thread and what a changed model drops. */
#define _GNU_SOURCE
#include "model_ref.h"

#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gazesplat/face.h"
#include "hash.h"
#include "log.h"
#include "store.h"

void gsd_model_unref(gsd_model *m)
{
    if (!m || atomic_fetch_sub(&m->refs, 1) != 1)
        return;
    gs_model_destroy(m->m);
    free(m);
}

gsd_model *gsd_model_acquire(gsd_server *s)
{
    pthread_mutex_lock(&s->model_mu);
    gsd_model *m = s->model;
    if (m)
        atomic_fetch_add(&m->refs, 1);
    pthread_mutex_unlock(&s->model_mu);
    return m;
}

const struct gs_model *gsd_model_get(gsd_server *s, gsd_model **ref)
{
    *ref = gsd_model_acquire(s);
    return *ref ? (*ref)->m : NULL;
}

void gsd_model_put(gsd_model *ref)
{
    gsd_model_unref(ref);
}

int gsd_model_image_size(gsd_server *s, char id[33])
{
    pthread_mutex_lock(&s->model_mu);
    int size = s->model ? s->model->image_size : 0;
    snprintf(id, 33, "%s", s->model ? s->model->id : "");
    pthread_mutex_unlock(&s->model_mu);
    return size;
}

/* The id is a hash of the file's bytes: subjects belong to one model. */
static int file_id(const char *path, char id[33], char *msg, size_t cap)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        snprintf(msg, cap, "%s: %s", path, strerror(errno));
        return -1;
    }
    hash128 h;
    hash_init(&h);
    unsigned char buf[65536];
    ssize_t n;
    while ((n = read(fd, buf, sizeof buf)) > 0)
        hash_bytes(&h, buf, (size_t)n);
    close(fd);
    if (n < 0) {
        snprintf(msg, cap, "%s: %s", path, strerror(errno));
        return -1;
    }
    uint8_t raw[16];
    hash_out(&h, raw);
    gs_frame_key_hex(raw, id);
    return 0;
}

static void *loader_main(void *p)
{
    gsd_server *s = p;
    gsd_model *m = calloc(1, sizeof *m);
    s->loaded = NULL;
    s->load_status = -1;
    if (!m) {
        snprintf(s->load_msg, sizeof s->load_msg, "out of memory");
    } else {
        snprintf(m->path, sizeof m->path, "%s", s->cfg.model);
        atomic_store(&m->refs, 1);
        if (file_id(m->path, m->id, s->load_msg, sizeof s->load_msg) == 0) {
            gs_error err;
            gs_error_clear(&err);
            if (gs_model_load(m->path, &m->m, &err) == GS_OK) {
                gs_model_get_info(m->m, &m->info);
                m->image_size = m->info.image_size;
                s->loaded = m;
                s->load_status = 0;
                m = NULL;
            } else {
                snprintf(s->load_msg, sizeof s->load_msg, "%.500s: %.256s", m->path, err.msg);
            }
        }
        free(m);
    }
    /* The landmark model (about 100 MB) is read once, with the first model. */
    if (s->cfg.photo_input && !s->face_sp && atomic_load(&s->photo_state) == 0) {
        gs_error ferr;
        gs_error_clear(&ferr);
        if (gs_face_shape_model_load(s->cfg.face_landmarks, &s->face_sp, &ferr) != GS_OK)
            snprintf(s->photo_msg, sizeof s->photo_msg, "%.280s", ferr.msg);
    }
    atomic_store(&s->load_done, 1);
    ev_wake(s->loop);
    return NULL;
}

int gsd_model_start_load(gsd_server *s, char *detail, size_t cap)
{
    if (s->loader_running) {
        LOG_W("a model load is already running");
        return -1;
    }
    if (!s->face_cascade[0])
        snprintf(s->face_cascade, sizeof s->face_cascade, "%s", s->cfg.face_cascade);
    if (!s->cfg.photo_input && atomic_load(&s->photo_state) == 0) {
        snprintf(s->photo_msg, sizeof s->photo_msg, "photo_input = no");
        atomic_store(&s->photo_state, -1);
    }
    if (!s->cfg.model[0]) {
        snprintf(detail, cap, "no model configured (model = PATH)");
        return GSD_FAILED;
    }
    int have = s->model != NULL;
    snprintf(detail, cap, "%s %s", have ? "reloading" : "loading", s->cfg.model);
    LOG_I("%s", detail);
    s->next_extend = ev_now_ms();
    if (pthread_create(&s->loader, NULL, loader_main, s) != 0) {
        snprintf(detail, cap, "cannot start the loader thread");
        return have ? GSD_READY : GSD_FAILED;
    }
    s->loader_running = 1;
    return have ? GSD_READY : GSD_LOADING;
}

int gsd_model_finish_load(gsd_server *s, char *detail, size_t cap, int *installed)
{
    *installed = 0;
    if (s->ready_sent)
        gsd_notify("READY=1"); /* a reload is over, whatever its outcome */
    pthread_join(s->loader, NULL);
    s->loader_running = 0;
    atomic_store(&s->load_done, 0);
    if (atomic_load(&s->photo_state) == 0 && s->cfg.photo_input) {
        atomic_store(&s->photo_state, s->face_sp ? 1 : -1);
        if (s->face_sp)
            LOG_I("photo input: landmarks %s, cascade %s", s->cfg.face_landmarks, s->face_cascade);
        else
            LOG_W("photo input unavailable: %s", s->photo_msg);
    }
    if (s->load_status != 0) {
        atomic_fetch_add(&s->ctr.model_load_failures, 1);
        LOG_E("model: %s", s->load_msg);
        snprintf(detail, cap, "%s%.700s", s->model ? "reload failed, serving the previous model: " : "",
                 s->load_msg);
        return s->model ? GSD_READY : GSD_FAILED;
    }
    gsd_model *m = s->loaded;
    s->loaded = NULL;
    atomic_fetch_add(&s->ctr.model_loads, 1);
    pthread_mutex_lock(&s->model_mu);
    gsd_model *old = s->model;
    s->model = m;
    pthread_mutex_unlock(&s->model_mu);
    if (!old) {
        gsd_cache_restore(s);
    } else if (strcmp(old->id, m->id) != 0) {
        LOG_I("model changed (%s -> %s): subjects dropped", old->id, m->id);
        gsd_cache_clear(s->cache);
        gsd_cache_clear(s->tuned);
        gsd_cache_clear(s->inputs);
        gsd_cache_persist(s);
        if (s->state_dir[0]) {
            pthread_mutex_lock(&s->persist_mu);
            gsd_store_sweep_all_locked(s); /* every block and input file goes */
            pthread_mutex_unlock(&s->persist_mu);
        }
    }
    gsd_model_unref(old);
    snprintf(detail, cap, "model %s (id %.16s, %d px)", m->path, m->id, m->image_size);
    LOG_I("ready: %s", detail);
    if (m->info.fit_code_prior > 0)
        LOG_I("fits use the model's code prior, weight %g", m->info.fit_code_prior);
    if (m->info.fit_code_rate > 0)
        LOG_I("fits use the model's code rate, %g", m->info.fit_code_rate);
    *installed = 1;
    return GSD_READY;
}

void gsd_model_release_all(gsd_server *s)
{
    gs_face_shape_model_destroy(s->face_sp);
    s->face_sp = NULL;
    if (s->loaded)
        gsd_model_unref(s->loaded);
    s->loaded = NULL;
    gsd_model_unref(s->model);
    s->model = NULL;
}

/* ---- the subject cache's file, named by the model's id ---------------------- */

void gsd_cache_restore(gsd_server *s)
{
    char id[33], msg[300];
    gsd_model_image_size(s, id);
    if (!s->state_dir[0]) {
        LOG_I("no state directory: subjects are not persisted");
        return;
    }
    int r = gsd_cache_load(s->cache, s->state_dir, id, msg, sizeof msg);
    if (r == 0)
        LOG_I("subject cache %s: %s", s->state_dir, msg);
    else
        LOG_W("subject cache %s: %s", s->state_dir, msg);
    gsd_store_restore(s, STORE_TUNED);
    gsd_store_restore(s, STORE_INPUT);
}

int gsd_cache_persist(gsd_server *s)
{
    char id[33], msg[300];
    if (!s->state_dir[0] || gsd_model_image_size(s, id) == 0)
        return 0;
    pthread_mutex_lock(&s->persist_mu);
    int r = gsd_cache_save(s->cache, s->state_dir, id, msg, sizeof msg);
    pthread_mutex_unlock(&s->persist_mu);
    atomic_fetch_add(r == 0 ? &s->ctr.cache_saves : &s->ctr.cache_save_failures, 1);
    if (r != 0)
        LOG_E("subject cache: %s", msg);
    return r;
}
