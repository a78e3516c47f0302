/*
 * accel_calib_fw: portable C99 encoder of the serial frames (no AVR headers).
 *
 * Data frame (interface spec section 1, 22 bytes):
 *   0xA5 0x5A | seq u8 | t_us u32 LE | 14 register bytes 0x3B..0x48 as read | crc8
 * Info frame (docs/firmware.md, 22 bytes):
 *   0xA5 0x49 | version | status | who_am_i | accel_g | gyro_dps u16 LE | rate_hz u16 LE
 *   | dlpf_cfg | baud u32 LE | fw_major | fw_minor | 'A' 'C' 'F' 'W' | crc8
 * CRC-8: polynomial 0x07, init 0, no reflection, no final xor, over bytes 2..20.
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#ifndef ACF_FRAME_H
#define ACF_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define ACF_FRAME_SIZE 22u
#define ACF_SYNC0 0xA5u
#define ACF_SYNC1_DATA 0x5Au
#define ACF_SYNC1_INFO 0x49u
#define ACF_INFO_VERSION 1u

/* Info frame status codes. */
#define ACF_STATUS_STREAMING 0u    /* known chip, configured, data frames follow */
#define ACF_STATUS_UNKNOWN_CHIP 1u /* WHO_AM_I not one of 0x71 0x73 0x70 0x68: no data */
#define ACF_STATUS_NO_SENSOR 2u    /* no ACK at 0x68 on the I2C bus: no data */
#define ACF_STATUS_CONFIG_FAILED 3u /* configuration did not read back: no data */

typedef struct {
    uint8_t status;
    uint8_t who_am_i;
    uint8_t accel_range_g;
    uint16_t gyro_range_dps;
    uint16_t rate_hz;
    uint8_t dlpf_cfg;
    uint32_t baud;
    uint8_t fw_major;
    uint8_t fw_minor;
} acf_info_t;

uint8_t acf_crc8(const uint8_t *data, size_t n);

/* Encode a data frame; regs are the 14 bytes read from registers 0x3B..0x48. */
void acf_encode_data(uint8_t out[ACF_FRAME_SIZE], uint8_t seq, uint32_t t_us,
                     const uint8_t regs[14]);

/* Encode an info frame. */
void acf_encode_info(uint8_t out[ACF_FRAME_SIZE], const acf_info_t *info);

#endif
