/*
 * accel_calib_fw: polled TWI (I2C) master for the ATmega328P, 400 kHz SCL, with bounded
 * waits and bus recovery.
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#ifndef ACF_TWI_H
#define ACF_TWI_H

#include <stdint.h>

/* Result of a transfer. */
#define TWI_OK 0u
#define TWI_NACK 1u        /* address or data byte not acknowledged */
#define TWI_TIMEOUT 2u     /* TWINT did not come within about 1 ms */
#define TWI_BUS_ERROR 3u   /* bus error or arbitration lost */

void twi_init(void);
/* Write one register; TWI_OK when every byte was acknowledged. */
uint8_t twi_write_reg(uint8_t addr7, uint8_t reg, uint8_t value);
/* Burst-read n >= 1 registers from reg on. */
uint8_t twi_read_regs(uint8_t addr7, uint8_t reg, uint8_t *out, uint8_t n);
/* 1 when SDA (PC4) reads low while the bus should be idle: a slave holds it. */
uint8_t twi_sda_low(void);
/* Bus recovery: TWI off, 9 SCL pulses on PC5, a STOP condition, TWI re-initialised.
 * Return 1 when SDA is released (high) after the pulses, 0 when it is still held low. */
uint8_t twi_bus_recover(void);

#endif
