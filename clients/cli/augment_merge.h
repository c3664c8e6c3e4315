/* gazesplat augment --merge: the shards of one augment run made into its
 * unsharded outputs (augment_merge.c, docs/augment.md "Shards"). */
#ifndef GS_CLI_AUGMENT_MERGE_H
#define GS_CLI_AUGMENT_MERGE_H

#include "cli.h"

/* Merges the n (>= 2) finished shards in out into out/labels.jsonl and,
 * when the shards wrote HDF5, out/augment.h5: the unsharded run's bytes.
 * CLI_OK, or a failure already reported (cli_fail). */
int aug_merge(const cli_command *cmd, const char *out, long n);

#endif
