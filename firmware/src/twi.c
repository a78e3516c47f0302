/*
 * accel_calib_fw: polled TWI (I2C) master for the ATmega328P.
 *
 * SCL = F_CPU / (16 + 2 * TWBR * prescaler): TWBR 12, prescaler 1 gives 400 kHz at 16 MHz.
 * Every wait is bounded (about 1 ms), so a missing or stuck sensor never hangs the program.
 * Only the failure codes are checked (NACK, arbitration lost, bus error), which is exact on
 * silicon and also tolerant of emulators that report a neighbouring success code.
 *
 * Bus recovery (a slave that holds SDA low, typically after a reset in the middle of one of
 * its bytes): the TWI is switched off, SCL (PC5) is clocked 9 times by hand, open-drain style
 * (driven low, released high), so that the slave finishes its byte and lets SDA (PC4) go,
 * then a STOP (SDA low to high while SCL is high) ends the transfer it thought was running.
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#include <avr/io.h>
#include <util/delay.h>
#include <util/twi.h>

#include "twi.h"

#ifndef TWI_SCL_HZ
#define TWI_SCL_HZ 400000UL
#endif
#define TWBR_VALUE (((F_CPU / TWI_SCL_HZ) - 16UL) / 2UL)
#if TWBR_VALUE < 10 || TWBR_VALUE > 255
#error "TWI_SCL_HZ out of range for F_CPU with prescaler 1"
#endif
/* A polling loop iteration takes about 6 cycles: 2700 of them are about 1 ms at 16 MHz,
 * some 40 byte times at 400 kHz. */
#define TWI_WAIT_LOOPS 2700u
#define SDA _BV(PC4)
#define SCL _BV(PC5)

void twi_init(void)
{
    DDRC &= (uint8_t)~(SDA | SCL);
    PORTC |= SDA | SCL;             /* weak pull-ups; the breakout board has its own */
    TWSR = 0;                       /* prescaler 1 */
    TWBR = (uint8_t)TWBR_VALUE;
    TWCR = _BV(TWEN);
}

static uint8_t twi_wait(void)
{
    uint16_t n = 0;
    while (!(TWCR & _BV(TWINT))) {
        if (++n == TWI_WAIT_LOOPS)
            return TWI_TIMEOUT;
    }
    switch (TW_STATUS) {
    case TW_MT_SLA_NACK:
    case TW_MT_DATA_NACK:
    case TW_MR_SLA_NACK:
        return TWI_NACK;
    case TW_MT_ARB_LOST:
    case TW_BUS_ERROR:
        return TWI_BUS_ERROR;
    default:
        return TWI_OK;
    }
}

static void twi_stop(void)
{
    uint16_t n = 0;
    TWCR = _BV(TWINT) | _BV(TWEN) | _BV(TWSTO);
    while ((TWCR & _BV(TWSTO)) && ++n != TWI_WAIT_LOOPS)
        ;
}

static uint8_t twi_start(uint8_t sla)
{
    uint8_t st;
    TWCR = _BV(TWINT) | _BV(TWSTA) | _BV(TWEN);
    if ((st = twi_wait()) != TWI_OK)
        return st;
    TWDR = sla;
    TWCR = _BV(TWINT) | _BV(TWEN);
    return twi_wait();
}

static uint8_t twi_send(uint8_t byte)
{
    TWDR = byte;
    TWCR = _BV(TWINT) | _BV(TWEN);
    return twi_wait();
}

uint8_t twi_write_reg(uint8_t addr7, uint8_t reg, uint8_t value)
{
    uint8_t st = twi_start((uint8_t)(addr7 << 1));
    if (st == TWI_OK)
        st = twi_send(reg);
    if (st == TWI_OK)
        st = twi_send(value);
    twi_stop();
    return st;
}

uint8_t twi_read_regs(uint8_t addr7, uint8_t reg, uint8_t *out, uint8_t n)
{
    uint8_t i;
    uint8_t st = twi_start((uint8_t)(addr7 << 1));
    if (st == TWI_OK)
        st = twi_send(reg);
    if (st == TWI_OK)
        st = twi_start((uint8_t)((addr7 << 1) | 1u));
    for (i = 0; st == TWI_OK && i < n; ++i) {
        uint8_t last = (uint8_t)(i + 1u == n);
        uint16_t k = 0;
        TWCR = last ? (uint8_t)(_BV(TWINT) | _BV(TWEN))
                    : (uint8_t)(_BV(TWINT) | _BV(TWEN) | _BV(TWEA));
        while (!(TWCR & _BV(TWINT))) {
            if (++k == TWI_WAIT_LOOPS) {
                st = TWI_TIMEOUT;
                break;
            }
        }
        if (st == TWI_OK)
            out[i] = TWDR;
    }
    twi_stop();
    return st;
}

uint8_t twi_sda_low(void)
{
    return !(PINC & SDA);
}

/* Open drain by hand: low = output driving 0; high = input, pulled up. */
static void line_low(uint8_t pin)
{
    PORTC &= (uint8_t)~pin;
    DDRC |= pin;
}

static void line_release(uint8_t pin)
{
    DDRC &= (uint8_t)~pin;
    PORTC |= pin;
}

uint8_t twi_bus_recover(void)
{
    uint8_t pulses = 0;
    uint8_t released;
    TWCR = 0;                       /* the port pins are ours again */
    line_release(SDA);
    line_release(SCL);
    _delay_us(5);
    while (pulses < 9) {
        line_low(SCL);
        _delay_us(5);
        line_release(SCL);
        _delay_us(5);
        ++pulses;
    }
    released = (PINC & SDA) != 0;
    /* STOP: SDA low while SCL low, SCL high, then SDA high. */
    line_low(SCL);
    _delay_us(5);
    line_low(SDA);
    _delay_us(5);
    line_release(SCL);
    _delay_us(5);
    line_release(SDA);
    _delay_us(5);
    twi_init();
    return released;
}
