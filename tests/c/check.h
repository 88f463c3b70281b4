/* Checks shared by the C tests of the bass C ABI (tests/c/abi_test.c and
 * tests/faults/c/abi_abuse.c): EXPECT compares a call's bass_result with the documented
 * code, CHECK any condition; both count, report a failure with file and line (EXPECT also
 * with the library's last error) and go on. main() ends with `failures == 0`.
 * Include after bass.h, once per program. */
#ifndef BASS_TEST_CHECK_H
#define BASS_TEST_CHECK_H

#include <stdint.h>
#include <stdio.h>

#include "bass.h"

static int failures, checks;

#define EXPECT(call, code)                                                                      \
    do {                                                                                        \
        bass_result r_ = (call);                                                                \
        checks++;                                                                               \
        if (r_ != (code)) {                                                                     \
            failures++;                                                                         \
            fprintf(stderr, "%s:%d: %s returned %d (%s), expected %d (%s); last error: %s\n",    \
                    __FILE__, __LINE__, #call, (int)r_, bass_result_str((int)r_), (int)(code),  \
                    bass_result_str((int)(code)), bass_last_error());                           \
        }                                                                                       \
    } while (0)

#define CHECK(cond)                                                                  \
    do {                                                                             \
        checks++;                                                                    \
        if (!(cond)) {                                                               \
            failures++;                                                              \
            fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                            \
    } while (0)

/* The test signal: frame index (26 bits) and channel (6 bits) in one sample, so that a
 * sample read back names where it came from. */
static inline int32_t pattern(uint64_t frame, unsigned ch) {
    return (int32_t)((uint32_t)((frame & 0x3FFFFFFu) << 6) | (ch & 63u));
}

#endif
