/* make fuzz: the receive parser against N corrupted frames (default 10^6), one report line per
 * figure. Exit status 1 on any false accept or any duplicate handed over twice. */
#include <stdio.h>
#include <stdlib.h>

#include "fuzz.h"

void board_tx_kick(void) {} /* frame.c's transmit side is not used here */

int main(int argc, char **argv)
{
    unsigned long long n = argc > 1 ? strtoull(argv[1], NULL, 10) : 1000000ull;
    unsigned long seed = argc > 2 ? strtoul(argv[2], NULL, 10) : 1ul;
    fuzz_result_t r = fuzz_frames((uint32_t)seed, n);
    printf("C core parser (firmware/core/frame.c), seed %lu\n", seed);
    printf("  frames %llu, corrupted %llu (", (unsigned long long)r.frames,
           (unsigned long long)r.corrupted);
    for (int i = 0; i < 6; i++)
        printf("%s%s %llu", i ? ", " : "", fuzz_op_names[i], (unsigned long long)r.by_op[i]);
    printf(")\n  intact %llu, delivered %llu, crc_errors %u, resyncs %u, duplicates dropped %u\n",
           (unsigned long long)r.intact, (unsigned long long)r.delivered, r.crc_errors, r.resyncs,
           r.dup_dropped);
    printf("  FALSE ACCEPTS %llu, duplicates executed %llu\n", (unsigned long long)r.false_accepts,
           (unsigned long long)r.duplicates_run);
    return r.false_accepts || r.duplicates_run ? 1 : 0;
}
