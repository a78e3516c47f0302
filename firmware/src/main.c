/*
 * accel_calib_fw: MPU-9250/9255/6500/6050 to the serial frame of interface spec section 1.
 *
 * ATmega328P at 16 MHz (Arduino Uno). Sensor at I2C address 0x68 (400 kHz SCL), its INT
 * pin on INT0 (PD2, Arduino D2), UART0 8N1 at FW_BAUD. Every data-ready interrupt
 * increments seq and stamps t_us (micros() from Timer1, 0.5 us resolution); the main loop
 * then clears INT_STATUS, burst-reads 0x3B..0x48 and queues one 22-byte frame. A sample
 * the program could not read or send (transmit ring full) is not sent: it shows as a gap
 * in seq. An info frame (chip, ranges, rate, baud) is sent at start-up, on request
 * ('?' or 'I' received) and, when no data can be streamed, once a second.
 *
 * Build-time settings (make variables): FW_BAUD, FW_RATE_HZ (divides 1000),
 * FW_ACCEL_RANGE_G (2 4 8 16), FW_GYRO_RANGE_DPS (250 500 1000 2000), FW_DLPF_CFG (1..6).
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <util/delay.h>

#include "frame.h"
#include "twi.h"
#include "uart.h"

#ifndef FW_BAUD
#define FW_BAUD 1000000UL
#endif
#ifndef FW_RATE_HZ
#define FW_RATE_HZ 1000
#endif
#ifndef FW_ACCEL_RANGE_G
#define FW_ACCEL_RANGE_G 2
#endif
#ifndef FW_GYRO_RANGE_DPS
#define FW_GYRO_RANGE_DPS 250
#endif
#ifndef FW_DLPF_CFG
#define FW_DLPF_CFG 1  /* gyro 184 Hz, internal rate 1 kHz (0 would mean 8 kHz) */
#endif
#define FW_MAJOR 1
#define FW_MINOR 0

#if FW_RATE_HZ < 4 || FW_RATE_HZ > 1000 || (1000 % FW_RATE_HZ) != 0
#error "FW_RATE_HZ must divide 1000 (4..1000)"
#endif
#if FW_DLPF_CFG < 1 || FW_DLPF_CFG > 6
#error "FW_DLPF_CFG must be 1..6 (0 and 7 run the sensor at 8 kHz)"
#endif
#if FW_ACCEL_RANGE_G == 2
#define AFS_SEL 0
#elif FW_ACCEL_RANGE_G == 4
#define AFS_SEL 1
#elif FW_ACCEL_RANGE_G == 8
#define AFS_SEL 2
#elif FW_ACCEL_RANGE_G == 16
#define AFS_SEL 3
#else
#error "FW_ACCEL_RANGE_G must be 2, 4, 8 or 16"
#endif
#if FW_GYRO_RANGE_DPS == 250
#define FS_SEL 0
#elif FW_GYRO_RANGE_DPS == 500
#define FS_SEL 1
#elif FW_GYRO_RANGE_DPS == 1000
#define FS_SEL 2
#elif FW_GYRO_RANGE_DPS == 2000
#define FS_SEL 3
#else
#error "FW_GYRO_RANGE_DPS must be 250, 500, 1000 or 2000"
#endif

#define MPU_ADDR 0x68
#define REG_SMPLRT_DIV 0x19
#define REG_CONFIG 0x1A
#define REG_GYRO_CONFIG 0x1B
#define REG_ACCEL_CONFIG 0x1C
#define REG_ACCEL_CONFIG2 0x1D
#define REG_INT_PIN_CFG 0x37
#define REG_INT_ENABLE 0x38
#define REG_INT_STATUS 0x3A
#define REG_ACCEL_XOUT_H 0x3B
#define REG_PWR_MGMT_1 0x6B
#define REG_PWR_MGMT_2 0x6C
#define REG_WHO_AM_I 0x75

#define SMPLRT_DIV_VALUE ((1000 / FW_RATE_HZ) - 1)

/* Timer1 at F_CPU / 8 = 2 MHz: micros = overflows * 32768 + TCNT1 / 2 (wraps at 2^32). */
static volatile uint32_t t1_overflows;
static volatile uint8_t drdy_count;
static volatile uint32_t drdy_t_us;

ISR(TIMER1_OVF_vect)
{
    ++t1_overflows;
}

ISR(INT0_vect)
{
    uint16_t c = TCNT1;
    uint32_t o = t1_overflows;
    if ((TIFR1 & _BV(TOV1)) && c < 0x8000u)
        ++o;                            /* overflow pending, not yet counted */
    drdy_t_us = (o << 15) + (c >> 1);
    ++drdy_count;
}

static void timer_init(void)
{
    TCCR1A = 0;
    TCCR1B = _BV(CS11);                 /* prescaler 8 */
    TIMSK1 = _BV(TOIE1);
}

static acf_info_t info;

static void send_info(void)
{
    uint8_t frame[ACF_FRAME_SIZE];
    acf_encode_info(frame, &info);
    while (uart_tx_free() < ACF_FRAME_SIZE)
        ;                               /* rare: wait for room rather than drop it */
    uart_write(frame, ACF_FRAME_SIZE);
}

static uint8_t known_chip(uint8_t who)
{
    return who == 0x71 || who == 0x73 || who == 0x70 || who == 0x68;
}

static uint8_t configure(uint8_t who)
{
    uint8_t back[4];
    uint8_t ok = twi_write_reg(MPU_ADDR, REG_PWR_MGMT_1, 0x80);  /* device reset */
    _delay_ms(100);
    ok &= twi_write_reg(MPU_ADDR, REG_PWR_MGMT_1, 0x01);        /* wake, PLL clock */
    _delay_ms(10);
    ok &= twi_write_reg(MPU_ADDR, REG_PWR_MGMT_2, 0x00);        /* all axes on */
    ok &= twi_write_reg(MPU_ADDR, REG_SMPLRT_DIV, SMPLRT_DIV_VALUE);
    ok &= twi_write_reg(MPU_ADDR, REG_CONFIG, FW_DLPF_CFG);
    ok &= twi_write_reg(MPU_ADDR, REG_GYRO_CONFIG, FS_SEL << 3); /* FCHOICE_B = 0 */
    ok &= twi_write_reg(MPU_ADDR, REG_ACCEL_CONFIG, AFS_SEL << 3);
    if (who != 0x68)                    /* 6500/9250/9255: accel DLPF, ACCEL_FCHOICE_B 0 */
        ok &= twi_write_reg(MPU_ADDR, REG_ACCEL_CONFIG2, FW_DLPF_CFG);
    /* INT: active high, push-pull, 50 us pulse, cleared by reading INT_STATUS. */
    ok &= twi_write_reg(MPU_ADDR, REG_INT_PIN_CFG, 0x00);
    ok &= twi_write_reg(MPU_ADDR, REG_INT_ENABLE, 0x01);        /* data ready */
    if (!ok || !twi_read_regs(MPU_ADDR, REG_SMPLRT_DIV, back, 4))
        return 0;
    return back[0] == SMPLRT_DIV_VALUE && (back[1] & 0x07) == FW_DLPF_CFG &&
        (back[2] & 0x1B) == (FS_SEL << 3) && (back[3] & 0x18) == (AFS_SEL << 3);
}

int main(void)
{
    uint8_t who = 0;
    uint8_t attempt;
    uint8_t last_count;
    uint8_t regs[14];
    uint8_t status;
    uint8_t frame[ACF_FRAME_SIZE];

    timer_init();
    uart_init(FW_BAUD);
    twi_init();
    sei();
    _delay_ms(100);                     /* sensor start-up time */

    status = ACF_STATUS_NO_SENSOR;
    for (attempt = 0; attempt < 5; ++attempt) {
        if (twi_read_regs(MPU_ADDR, REG_WHO_AM_I, &who, 1)) {
            status = known_chip(who) ? ACF_STATUS_STREAMING : ACF_STATUS_UNKNOWN_CHIP;
            break;
        }
        _delay_ms(20);
    }
    if (status == ACF_STATUS_STREAMING && !configure(who))
        status = ACF_STATUS_CONFIG_FAILED;

    info.status = status;
    info.who_am_i = who;
    info.accel_range_g = FW_ACCEL_RANGE_G;
    info.gyro_range_dps = FW_GYRO_RANGE_DPS;
    info.rate_hz = FW_RATE_HZ;
    info.dlpf_cfg = FW_DLPF_CFG;
    info.baud = FW_BAUD;
    info.fw_major = FW_MAJOR;
    info.fw_minor = FW_MINOR;

    if (status != ACF_STATUS_STREAMING) {
        for (;;) {                      /* report, never stream as if it were a known chip */
            uint8_t tenth;
            send_info();
            for (tenth = 0; tenth < 100 && !uart_take_request(); ++tenth)
                _delay_ms(10);
        }
    }

    send_info();
    twi_read_regs(MPU_ADDR, REG_INT_STATUS, regs, 1);           /* clear a stale flag */
    last_count = drdy_count;
    EICRA = _BV(ISC01) | _BV(ISC00);    /* INT0 on the rising edge */
    EIFR = _BV(INTF0);
    EIMSK = _BV(INT0);

    for (;;) {
        uint8_t count;
        uint32_t t_us;
        cli();
        count = drdy_count;
        t_us = drdy_t_us;
        if (count == last_count && !uart_take_request()) {
            set_sleep_mode(SLEEP_MODE_IDLE);   /* UART and timers keep running */
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
            continue;
        }
        sei();
        if (count == last_count) {      /* woken by a request */
            send_info();
            continue;
        }
        last_count = count;
        /* INT_STATUS first (clears the interrupt), then the 14-byte burst. */
        if (twi_read_regs(MPU_ADDR, REG_INT_STATUS, frame, 1) &&
                twi_read_regs(MPU_ADDR, REG_ACCEL_XOUT_H, regs, 14) &&
                uart_tx_free() >= ACF_FRAME_SIZE) {
            acf_encode_data(frame, count, t_us, regs);
            uart_write(frame, ACF_FRAME_SIZE);
        }
    }
}
