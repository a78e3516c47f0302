/*
 * accel_calib_fw: portable C99 frame encoder (see frame.h).
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#include "frame.h"

uint8_t acf_crc8(const uint8_t *data, size_t n)
{
    uint8_t crc = 0;
    size_t i;
    for (i = 0; i < n; ++i) {
        uint8_t bit;
        crc ^= data[i];
        for (bit = 0; bit < 8; ++bit)
            crc = (crc & 0x80u) ? (uint8_t)((crc << 1) ^ 0x07u) : (uint8_t)(crc << 1);
    }
    return crc;
}

static void put_u16le(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32le(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

void acf_encode_data(uint8_t out[ACF_FRAME_SIZE], uint8_t seq, uint32_t t_us,
                     const uint8_t regs[14])
{
    uint8_t i;
    out[0] = ACF_SYNC0;
    out[1] = ACF_SYNC1_DATA;
    out[2] = seq;
    put_u32le(out + 3, t_us);
    for (i = 0; i < 14; ++i)
        out[7 + i] = regs[i];
    out[21] = acf_crc8(out + 2, 19);
}

void acf_encode_info(uint8_t out[ACF_FRAME_SIZE], const acf_info_t *info)
{
    out[0] = ACF_SYNC0;
    out[1] = ACF_SYNC1_INFO;
    out[2] = ACF_INFO_VERSION;
    out[3] = info->status;
    out[4] = info->who_am_i;
    out[5] = info->accel_range_g;
    put_u16le(out + 6, info->gyro_range_dps);
    put_u16le(out + 8, info->rate_hz);
    out[10] = info->dlpf_cfg;
    put_u32le(out + 11, info->baud);
    out[15] = info->fw_major;
    out[16] = info->fw_minor;
    out[17] = 'A';
    out[18] = 'C';
    out[19] = 'F';
    out[20] = 'W';
    out[21] = acf_crc8(out + 2, 19);
}
