/* Corrupted-stream fuzz of the firmware's receive parser (frame.c), on the host. */
#ifndef FUZZ_H
#define FUZZ_H
#include <stdint.h>

typedef struct {
    uint64_t frames;         /* frames put on the line */
    uint64_t corrupted;      /* of which damaged (flip, drop, insert, duplicate, truncate, burst) */
    uint64_t intact;         /* sent untouched (a duplicated frame counts once) */
    uint64_t delivered;      /* frames the parser handed over, byte-identical to one sent */
    uint64_t false_accepts;  /* frames handed over that were never sent as such */
    uint64_t duplicates_run; /* a repeated frame handed over a second time */
    uint64_t by_op[6];       /* corrupted frames per kind, as in fuzz_op_names */
    uint32_t crc_errors, resyncs, dup_dropped; /* parser counters, summed over the run */
} fuzz_result_t;

extern const char *const fuzz_op_names[6];
/* Run until `corrupted` frames have been damaged (about half of all frames are), seeded. */
fuzz_result_t fuzz_frames(uint32_t seed, uint64_t corrupted);

#endif
