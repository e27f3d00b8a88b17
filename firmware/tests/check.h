/* A minimal assertion kit for the host unit tests: failures are counted and reported with the
 * file and line; main() exits non-zero if any failed. */
#ifndef CHECK_H
#define CHECK_H
#include <stdio.h>

extern int check_failures, check_count;

#define CHECK(cond, ...)                                                                   \
    do {                                                                                   \
        check_count++;                                                                     \
        if (!(cond)) {                                                                     \
            check_failures++;                                                              \
            fprintf(stderr, "%s:%d: CHECK(%s) failed: ", __FILE__, __LINE__, #cond);       \
            fprintf(stderr, __VA_ARGS__);                                                  \
            fputc('\n', stderr);                                                           \
        }                                                                                  \
    } while (0)

#define CHECK_EQ(a, b)                                                                     \
    CHECK((long long)(a) == (long long)(b), "%s = %lld, expected %s = %lld", #a,          \
          (long long)(a), #b, (long long)(b))

#endif
