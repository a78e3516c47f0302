/*
 * accel_calib_fw: portable C99 encoder of the serial frames (no AVR headers).
 *
 * Data frame version 2 (interface spec section 1b, 25 bytes, 32 with the AK8963 block):
 *   0xA5 0x5B | flags | seq u16 LE | t_us u32 LE | 14 register bytes 0x3B..0x48 as read
 *   [| HXL HXH HYL HYH HZL HZH ST2 (flags bit 0)] | crc16 LE
 *   CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over bytes 2 .. end-2.
 * Data frame version 1 (interface spec section 1, 22 bytes):
 *   0xA5 0x5A | seq u8 | t_us u32 LE | 14 register bytes 0x3B..0x48 as read | crc8
 *   CRC-8: polynomial 0x07, init 0, no reflection, no final xor, over bytes 2..20.
 * Info frame version 2 (docs/firmware.md, 34 bytes, CRC-16 as the data frame):
 *   0xA5 0x4A | 2 | status | who_am_i | accel_g | gyro_dps u16 | rate_hz u16 | dlpf_cfg
 *   | baud u32 | fw_major | fw_minor | frame_version | mag | ASA x y z | recoveries u16
 *   | i2c_errors u16 | last_recovery | 0 | 'A' 'C' 'F' 'W' | crc16    (integers LE)
 * Info frame version 1 (firmware 1.x, 22 bytes, CRC-8 as the version-1 data frame):
 *   0xA5 0x49 | 1 | status | who_am_i | accel_g | gyro_dps u16 LE | rate_hz u16 LE
 *   | dlpf_cfg | baud u32 LE | fw_major | fw_minor | 'A' 'C' 'F' 'W' | crc8
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#ifndef ACF_FRAME_H
#define ACF_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define ACF_FRAME_SIZE 22u          /* version 1 */
#define ACF_FRAME_V2_SIZE 25u       /* version 2 without the magnetometer block */
#define ACF_FRAME_V2_MAG_SIZE 32u   /* version 2 with it */
#define ACF_FRAME_MAX_SIZE 34u      /* the largest frame of any kind (info version 2) */
#define ACF_INFO_V2_SIZE 34u
#define ACF_SYNC0 0xA5u
#define ACF_SYNC1_DATA 0x5Au
#define ACF_SYNC1_DATA_V2 0x5Bu
#define ACF_SYNC1_INFO 0x49u
#define ACF_SYNC1_INFO_V2 0x4Au
#define ACF_INFO_VERSION 1u
#define ACF_FLAG_MAG 0x01u

/* Info frame status codes. */
#define ACF_STATUS_STREAMING 0u    /* known chip, configured, data frames follow */
#define ACF_STATUS_UNKNOWN_CHIP 1u /* WHO_AM_I not one of 0x71 0x73 0x70 0x68: no data */
#define ACF_STATUS_NO_SENSOR 2u    /* no ACK at 0x68 on the I2C bus: no data */
#define ACF_STATUS_CONFIG_FAILED 3u /* configuration did not read back: no data */

/* Info frame magnetometer field. */
#define ACF_MAG_ABSENT 0u          /* no AK8963 answers (MPU-6500/6050, or none wired) */
#define ACF_MAG_AK8963 1u          /* AK8963 found, 16-bit continuous mode 2 (100 Hz) */
#define ACF_MAG_FAILED 2u          /* AK8963 answered but did not accept its configuration */

/* Cause of the last recovery. */
#define ACF_CAUSE_NONE 0u
#define ACF_CAUSE_DRDY 1u          /* data-ready silent */
#define ACF_CAUSE_NACK 2u          /* I2C transfer not acknowledged */
#define ACF_CAUSE_TIMEOUT 3u       /* I2C transfer timed out */
#define ACF_CAUSE_SDA_STUCK 4u     /* I2C bus stuck: SDA held low */

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
    /* version 2 only */
    uint8_t frame_version;
    uint8_t mag;
    uint8_t asa[3];
    uint16_t recoveries;
    uint16_t i2c_errors;
    uint8_t last_recovery;
} acf_info_t;

uint8_t acf_crc8(const uint8_t *data, size_t n);
uint16_t acf_crc16(const uint8_t *data, size_t n);

/* Encode a version-1 data frame; regs are the 14 bytes read from registers 0x3B..0x48. */
void acf_encode_data(uint8_t out[ACF_FRAME_SIZE], uint8_t seq, uint32_t t_us,
                     const uint8_t regs[14]);

/* Encode a version-2 data frame; mag is NULL or the 7 bytes HXL..HZH ST2 as read from the
 * AK8963. Return the frame's length (25 or 32). */
uint8_t acf_encode_data_v2(uint8_t out[ACF_FRAME_V2_MAG_SIZE], uint16_t seq, uint32_t t_us,
                           const uint8_t regs[14], const uint8_t *mag);

/* Encode an info frame, version 1 layout (22 bytes). */
void acf_encode_info(uint8_t out[ACF_FRAME_SIZE], const acf_info_t *info);

/* Encode an info frame, version 2 layout (34 bytes). */
void acf_encode_info_v2(uint8_t out[ACF_INFO_V2_SIZE], const acf_info_t *info);

#endif
