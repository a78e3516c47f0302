/*
 * Host test driver of the portable frame encoder (compiled with the host cc).
 *
 * Reads lines from stdin and prints each encoded frame as 44 hex digits:
 *   D seq t_us c0 c1 c2 c3 c4 c5 c6    data frame (counts as signed int16)
 *   I status who accel gyro rate dlpf baud major minor    info frame
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#include <stdio.h>
#include <stdlib.h>

#include "frame.h"

static void print_frame(const uint8_t *f)
{
    unsigned i;
    for (i = 0; i < ACF_FRAME_SIZE; ++i)
        printf("%02x", f[i]);
    putchar('\n');
}

int main(void)
{
    char kind;
    uint8_t out[ACF_FRAME_SIZE];
    while (scanf(" %c", &kind) == 1) {
        if (kind == 'D') {
            unsigned long seq, t;
            long c[7];
            uint8_t regs[14];
            int i;
            if (scanf("%lu %lu %ld %ld %ld %ld %ld %ld %ld", &seq, &t, &c[0], &c[1], &c[2],
                      &c[3], &c[4], &c[5], &c[6]) != 9)
                return 2;
            for (i = 0; i < 7; ++i) {
                uint16_t v = (uint16_t)(int16_t)c[i];
                regs[2 * i] = (uint8_t)(v >> 8);       /* registers are big-endian */
                regs[2 * i + 1] = (uint8_t)(v & 0xFFu);
            }
            acf_encode_data(out, (uint8_t)seq, (uint32_t)t, regs);
        } else if (kind == 'I') {
            unsigned long v[9];
            acf_info_t info;
            if (scanf("%lu %lu %lu %lu %lu %lu %lu %lu %lu", &v[0], &v[1], &v[2], &v[3], &v[4],
                      &v[5], &v[6], &v[7], &v[8]) != 9)
                return 2;
            info.status = (uint8_t)v[0];
            info.who_am_i = (uint8_t)v[1];
            info.accel_range_g = (uint8_t)v[2];
            info.gyro_range_dps = (uint16_t)v[3];
            info.rate_hz = (uint16_t)v[4];
            info.dlpf_cfg = (uint8_t)v[5];
            info.baud = (uint32_t)v[6];
            info.fw_major = (uint8_t)v[7];
            info.fw_minor = (uint8_t)v[8];
            acf_encode_info(out, &info);
        } else {
            return 2;
        }
        print_frame(out);
    }
    return 0;
}
