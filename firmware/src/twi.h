/*
 * accel_calib_fw: polled TWI (I2C) master for the ATmega328P, 400 kHz SCL.
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#ifndef ACF_TWI_H
#define ACF_TWI_H

#include <stdint.h>

void twi_init(void);
/* Write one register; return 1 on success (every byte ACKed). */
uint8_t twi_write_reg(uint8_t addr7, uint8_t reg, uint8_t value);
/* Burst-read n >= 1 registers from reg on; return 1 on success. */
uint8_t twi_read_regs(uint8_t addr7, uint8_t reg, uint8_t *out, uint8_t n);

#endif
