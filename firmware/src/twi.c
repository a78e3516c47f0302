/*
 * accel_calib_fw: polled TWI (I2C) master for the ATmega328P.
 *
 * SCL = F_CPU / (16 + 2 * TWBR * prescaler): TWBR 12, prescaler 1 gives 400 kHz at 16 MHz.
 * Every wait is bounded, so a missing or stuck sensor never hangs the program. Only the
 * failure codes are checked (NACK, arbitration lost, bus error), which is exact on silicon
 * and also tolerant of emulators that report a neighbouring success code.
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#include <avr/io.h>
#include <util/twi.h>

#include "twi.h"

#ifndef TWI_SCL_HZ
#define TWI_SCL_HZ 400000UL
#endif
#define TWBR_VALUE (((F_CPU / TWI_SCL_HZ) - 16UL) / 2UL)
#if TWBR_VALUE < 10 || TWBR_VALUE > 255
#error "TWI_SCL_HZ out of range for F_CPU with prescaler 1"
#endif

void twi_init(void)
{
    PORTC |= _BV(PC4) | _BV(PC5);   /* weak pull-ups; the breakout board has its own */
    TWSR = 0;                       /* prescaler 1 */
    TWBR = (uint8_t)TWBR_VALUE;
    TWCR = _BV(TWEN);
}

static uint8_t twi_wait(void)
{
    uint16_t n = 0;
    while (!(TWCR & _BV(TWINT))) {
        if (++n == 0)               /* about 25 ms at 16 MHz: give up */
            return 0;
    }
    return 1;
}

static uint8_t twi_failed(void)
{
    uint8_t st = TW_STATUS;
    return st == TW_MT_SLA_NACK || st == TW_MT_DATA_NACK || st == TW_MR_SLA_NACK ||
        st == TW_MT_ARB_LOST || st == TW_BUS_ERROR;
}

static void twi_stop(void)
{
    uint16_t n = 0;
    TWCR = _BV(TWINT) | _BV(TWEN) | _BV(TWSTO);
    while ((TWCR & _BV(TWSTO)) && ++n != 0)
        ;
}

static uint8_t twi_start(uint8_t sla)
{
    TWCR = _BV(TWINT) | _BV(TWSTA) | _BV(TWEN);
    if (!twi_wait() || twi_failed())
        return 0;
    TWDR = sla;
    TWCR = _BV(TWINT) | _BV(TWEN);
    return twi_wait() && !twi_failed();
}

static uint8_t twi_send(uint8_t byte)
{
    TWDR = byte;
    TWCR = _BV(TWINT) | _BV(TWEN);
    return twi_wait() && !twi_failed();
}

uint8_t twi_write_reg(uint8_t addr7, uint8_t reg, uint8_t value)
{
    uint8_t ok = twi_start((uint8_t)(addr7 << 1)) && twi_send(reg) && twi_send(value);
    twi_stop();
    return ok;
}

uint8_t twi_read_regs(uint8_t addr7, uint8_t reg, uint8_t *out, uint8_t n)
{
    uint8_t i;
    if (!(twi_start((uint8_t)(addr7 << 1)) && twi_send(reg) &&
          twi_start((uint8_t)((addr7 << 1) | 1u)))) {
        twi_stop();
        return 0;
    }
    for (i = 0; i < n; ++i) {
        uint8_t last = (uint8_t)(i + 1u == n);
        TWCR = last ? (uint8_t)(_BV(TWINT) | _BV(TWEN))
                    : (uint8_t)(_BV(TWINT) | _BV(TWEN) | _BV(TWEA));
        if (!twi_wait()) {
            twi_stop();
            return 0;
        }
        out[i] = TWDR;
    }
    twi_stop();
    return 1;
}
