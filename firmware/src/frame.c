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

/* CRC-16/CCITT-FALSE, one byte at a time without a table (about 20 AVR cycles a byte). */
uint16_t acf_crc16(const uint8_t *data, size_t n)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    for (i = 0; i < n; ++i) {
        uint16_t x = (uint16_t)(((crc >> 8) ^ data[i]) & 0xFFu);
        x ^= x >> 4;
        crc = (uint16_t)((crc << 8) ^ (x << 12) ^ (x << 5) ^ x);
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

uint8_t acf_encode_data_v2(uint8_t out[ACF_FRAME_V2_MAG_SIZE], uint16_t seq, uint32_t t_us,
                           const uint8_t regs[14], const uint8_t *mag)
{
    uint8_t i;
    uint8_t n = 23;
    out[0] = ACF_SYNC0;
    out[1] = ACF_SYNC1_DATA_V2;
    out[2] = mag ? ACF_FLAG_MAG : 0u;
    put_u16le(out + 3, seq);
    put_u32le(out + 5, t_us);
    for (i = 0; i < 14; ++i)
        out[9 + i] = regs[i];
    if (mag) {
        for (i = 0; i < 7; ++i)
            out[23 + i] = mag[i];
        n = 30;
    }
    put_u16le(out + n, acf_crc16(out + 2, (size_t)(n - 2u)));
    return (uint8_t)(n + 2u);
}

static void put_common(uint8_t *out, const acf_info_t *info)
{
    out[3] = info->status;
    out[4] = info->who_am_i;
    out[5] = info->accel_range_g;
    put_u16le(out + 6, info->gyro_range_dps);
    put_u16le(out + 8, info->rate_hz);
    out[10] = info->dlpf_cfg;
    put_u32le(out + 11, info->baud);
    out[15] = info->fw_major;
    out[16] = info->fw_minor;
}

void acf_encode_info(uint8_t out[ACF_FRAME_SIZE], const acf_info_t *info)
{
    out[0] = ACF_SYNC0;
    out[1] = ACF_SYNC1_INFO;
    out[2] = ACF_INFO_VERSION;
    put_common(out, info);
    out[17] = 'A';
    out[18] = 'C';
    out[19] = 'F';
    out[20] = 'W';
    out[21] = acf_crc8(out + 2, 19);
}

void acf_encode_info_v2(uint8_t out[ACF_INFO_V2_SIZE], const acf_info_t *info)
{
    out[0] = ACF_SYNC0;
    out[1] = ACF_SYNC1_INFO_V2;
    out[2] = 2u;
    put_common(out, info);
    out[17] = info->frame_version;
    out[18] = info->mag;
    out[19] = info->asa[0];
    out[20] = info->asa[1];
    out[21] = info->asa[2];
    put_u16le(out + 22, info->recoveries);
    put_u16le(out + 24, info->i2c_errors);
    out[26] = info->last_recovery;
    out[27] = 0u;
    out[28] = 'A';
    out[29] = 'C';
    out[30] = 'F';
    out[31] = 'W';
    put_u16le(out + 32, acf_crc16(out + 2, 30));
}
