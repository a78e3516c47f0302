/*
 * Host test driver of the portable frame encoder (compiled with the host cc).
 *
 * Reads lines from stdin and prints each encoded frame as hex digits, one frame a line:
 *   D seq t_us c0 c1 c2 c3 c4 c5 c6                 data frame version 1
 *   E seq t_us c0 .. c6 has_mag hx hy hz st2         data frame version 2 (counts int16;
 *                                                   the block only when has_mag is 1)
 *   I status who accel gyro rate dlpf baud major minor          info frame version 1
 *   J status who accel gyro rate dlpf baud major minor frame_version mag asa_x asa_y asa_z
 *     recoveries i2c_errors last_recovery                        info frame version 2
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#include <stdio.h>
#include <stdlib.h>

#include "frame.h"

static void print_frame(const uint8_t *f, unsigned n)
{
    unsigned i;
    for (i = 0; i < n; ++i)
        printf("%02x", f[i]);
    putchar('\n');
}

static void put_be16(uint8_t *p, long v)
{
    uint16_t u = (uint16_t)(int16_t)v;
    p[0] = (uint8_t)(u >> 8);
    p[1] = (uint8_t)(u & 0xFFu);
}

static void put_le16(uint8_t *p, long v)
{
    uint16_t u = (uint16_t)(int16_t)v;
    p[0] = (uint8_t)(u & 0xFFu);
    p[1] = (uint8_t)(u >> 8);
}

static int read_info(acf_info_t *info, int v2)
{
    unsigned long v[17];
    int i, n = v2 ? 17 : 9;
    for (i = 0; i < n; ++i)
        if (scanf("%lu", &v[i]) != 1)
            return 0;
    info->status = (uint8_t)v[0];
    info->who_am_i = (uint8_t)v[1];
    info->accel_range_g = (uint8_t)v[2];
    info->gyro_range_dps = (uint16_t)v[3];
    info->rate_hz = (uint16_t)v[4];
    info->dlpf_cfg = (uint8_t)v[5];
    info->baud = (uint32_t)v[6];
    info->fw_major = (uint8_t)v[7];
    info->fw_minor = (uint8_t)v[8];
    if (v2) {
        info->frame_version = (uint8_t)v[9];
        info->mag = (uint8_t)v[10];
        info->asa[0] = (uint8_t)v[11];
        info->asa[1] = (uint8_t)v[12];
        info->asa[2] = (uint8_t)v[13];
        info->recoveries = (uint16_t)v[14];
        info->i2c_errors = (uint16_t)v[15];
        info->last_recovery = (uint8_t)v[16];
    }
    return 1;
}

int main(void)
{
    char kind;
    uint8_t out[ACF_FRAME_MAX_SIZE];
    while (scanf(" %c", &kind) == 1) {
        if (kind == 'D' || kind == 'E') {
            unsigned long seq, t;
            long c[7], m[5];
            uint8_t regs[14], mag[7];
            int i;
            if (scanf("%lu %lu %ld %ld %ld %ld %ld %ld %ld", &seq, &t, &c[0], &c[1], &c[2],
                      &c[3], &c[4], &c[5], &c[6]) != 9)
                return 2;
            for (i = 0; i < 7; ++i)
                put_be16(regs + 2 * i, c[i]);             /* registers are big-endian */
            if (kind == 'D') {
                acf_encode_data(out, (uint8_t)seq, (uint32_t)t, regs);
                print_frame(out, ACF_FRAME_SIZE);
                continue;
            }
            if (scanf("%ld %ld %ld %ld %ld", &m[0], &m[1], &m[2], &m[3], &m[4]) != 5)
                return 2;
            for (i = 0; i < 3; ++i)
                put_le16(mag + 2 * i, m[1 + i]);          /* the AK8963 is little-endian */
            mag[6] = (uint8_t)m[4];
            print_frame(out, acf_encode_data_v2(out, (uint16_t)seq, (uint32_t)t, regs,
                                                m[0] ? mag : NULL));
        } else if (kind == 'I' || kind == 'J') {
            acf_info_t info;
            if (!read_info(&info, kind == 'J'))
                return 2;
            if (kind == 'I') {
                acf_encode_info(out, &info);
                print_frame(out, ACF_FRAME_SIZE);
            } else {
                acf_encode_info_v2(out, &info);
                print_frame(out, ACF_INFO_V2_SIZE);
            }
        } else {
            return 2;
        }
    }
    return 0;
}
