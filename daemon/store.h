/* What a daemon keeps of its subjects (store.c); the subject cache's file
 * is model_ref.c's (gsd_cache_restore, gsd_cache_persist in daemon.h). Besides its gs_subject (the subject
 * cache), a subject may have a fine-tuned block (STORE_TUNED) and a kept
 * input (STORE_INPUT), each kind in an LRU cache of its own and, with a
 * state directory, one file per subject. */
#ifndef GSD_STORE_H
#define GSD_STORE_H

#include "daemon.h"
#include "gazesplat/image_io.h"
#include "gazesplat/model.h"

enum { STORE_TUNED, STORE_INPUT, STORE_KINDS };

/* The subject's cache blob; sum non-NULL: a fine-tuned subject (the
 * block's checksum follows). Its length, 0 when cap is short. */
size_t gsd_subject_blob(const gs_subject *subj, const uint64_t *sum, uint8_t *blob, size_t cap);
/* The cached subject of key: 0, *tuned and *sum for a fine-tuned one; -1
 * when none or unreadable. */
int gsd_subject_lookup(gsd_server *s, const uint8_t key[16], gs_subject *subj, int *tuned, uint64_t *sum);
/* Keeps a blob of a kind in its cache and, with a state directory, on
 * disk; 0 or an ErrorCode with msg. */
int gsd_store_put(gsd_server *s, int kind, const uint8_t key[16], const uint8_t *blob, size_t len,
                  char *msg, size_t cap);
/* At start or a model change: the kind's files of cached subjects back
 * into its cache, within its budget, oldest first dropped. */
void gsd_store_restore(gsd_server *s, int kind);
/* Removes every kind's files whose blob left its cache (persist_mu held). */
void gsd_store_sweep_all_locked(gsd_server *s);
/* Keeps face (the model's size) as key's input, with what a photo says of
 * its eyes (eyes NULL, or its opening NULL: nothing; else the opening,
 * size^2 bytes, and its irises); 0 or an ErrorCode. */
int gsd_input_keep(gsd_server *s, const uint8_t key[16], const gs_io_image *face,
                   const gs_xfer_eyes *eyes, char *msg, size_t cap);
/* key's kept input as a size x size image (out->data malloc'd), and its
 * eyes: *opening malloc'd (NULL when it had none), *eyes with that opening
 * and the irises (none when it had none); -1 when there is none. Blobs kept
 * before the irises were, or before the opening was, still load. */
int gsd_input_get(gsd_server *s, const uint8_t key[16], int size, gs_io_image *out,
                  uint8_t **opening, gs_xfer_eyes *eyes);

#endif
