/*
 * accel_calib_fw: MPU-9250/9255/6500/6050 to the serial frames of interface spec 1b (or 1).
 *
 * ATmega328P at 16 MHz (Arduino Uno). Sensor at I2C address 0x68 (400 kHz SCL), its INT
 * pin on INT0 (PD2, Arduino D2), UART0 8N1 at FW_BAUD. Every data-ready interrupt stamps
 * t_us (micros() from Timer1, 0.5 us resolution); the main loop then clears INT_STATUS,
 * burst-reads 0x3B..0x48 and queues one frame (version 2 by default: 16-bit seq, CRC-16).
 * seq counts sensor samples: a sample the program could not read or send (transmit ring
 * full) shows as a gap in seq.
 *
 * Recovery: when data-ready stays silent for DRDY_TIMEOUT_US (20 ms at 1 kHz), or an I2C
 * transfer is not acknowledged, times out, or finds SDA held low, the program clocks the
 * bus free (9 SCL pulses, STOP), writes the sensor's configuration again and reads it back
 * (a full H_RESET only after five recoveries that configured it but brought no data-ready),
 * retrying every 5 ms while the sensor does not answer. The first sample after a recovery
 * advances seq by the sample periods that passed, so the receiver counts the loss. The info
 * frame (at start-up, on request '?' or 'I', after every recovery and once a second) carries
 * the recovery counters; when no sensor can be streamed it is sent once a second and the
 * sensor is probed again.
 *
 * Build-time settings (make variables): FW_BAUD, FW_RATE_HZ (divides 1000),
 * FW_ACCEL_RANGE_G (2 4 8 16), FW_GYRO_RANGE_DPS (250 500 1000 2000), FW_DLPF_CFG (1..6),
 * FW_FRAME_VERSION (2, or 1 for drivers that read only the version-1 frame).
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
#ifndef FW_FRAME_VERSION
#define FW_FRAME_VERSION 2
#endif
#define FW_MAJOR 2
#define FW_MINOR 0

#if FW_RATE_HZ < 4 || FW_RATE_HZ > 1000 || (1000 % FW_RATE_HZ) != 0
#error "FW_RATE_HZ must divide 1000 (4..1000)"
#endif
#if FW_DLPF_CFG < 1 || FW_DLPF_CFG > 6
#error "FW_DLPF_CFG must be 1..6 (0 and 7 run the sensor at 8 kHz)"
#endif
#if FW_FRAME_VERSION != 1 && FW_FRAME_VERSION != 2
#error "FW_FRAME_VERSION must be 1 or 2"
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
#define INT_PIN_CFG_VALUE 0x02  /* INT active high, push-pull, 50 us pulse; BYPASS_EN */

/* AK8963 (inside the MPU-9250/9255), reached in bypass mode at 0x0C. */
#define AK_ADDR 0x0C
#define AK_WIA 0x00
#define AK_WIA_VALUE 0x48
#define AK_ST1 0x02
#define AK_CNTL1 0x0A
#define AK_ASAX 0x10
#define AK_MODE_POWER_DOWN 0x00
#define AK_MODE_FUSE_ROM 0x0F
#define AK_MODE_16BIT_CONT2 0x16        /* BIT = 1 (16-bit), MODE = 0110 (100 Hz) */
#define AK_PERIOD_US 10000UL

#define SMPLRT_DIV_VALUE ((1000 / FW_RATE_HZ) - 1)
#define PERIOD_US (1000000UL / FW_RATE_HZ)
/* Data-ready silent this long means the sensor stopped: 20 ms, or 4 periods at low rates. */
#define DRDY_TIMEOUT_US (4UL * PERIOD_US > 20000UL ? 4UL * PERIOD_US : 20000UL)
#define RETRY_FAILED_US 5000UL          /* next attempt while the sensor does not answer */
#define INFO_EVERY_US 1000000UL
#define CONFIG_MISMATCH 0x10u           /* configure(): a register did not read back */
#define FULL_RESET_AFTER 5              /* fruitless recoveries before an H_RESET (100 ms) */

/* Timer1 at F_CPU / 8 = 2 MHz: micros = overflows * 32768 + TCNT1 / 2 (wraps at 2^32). */
static volatile uint32_t t1_overflows;
static volatile uint8_t drdy_count;
static volatile uint32_t drdy_t_us;
static volatile uint8_t tick;

ISR(TIMER1_OVF_vect)
{
    ++t1_overflows;
}

static uint32_t micros_locked(void)
{
    uint16_t c = TCNT1;
    uint32_t o = t1_overflows;
    if ((TIFR1 & _BV(TOV1)) && c < 0x8000u)
        ++o;                            /* overflow pending, not yet counted */
    return (o << 15) + (c >> 1);
}

static uint32_t micros(void)
{
    uint8_t sreg = SREG;
    uint32_t t;
    cli();
    t = micros_locked();
    SREG = sreg;
    return t;
}

ISR(INT0_vect)
{
    drdy_t_us = micros_locked();
    ++drdy_count;
}

ISR(TIMER2_COMPA_vect)
{
    tick = 1;                           /* 1 kHz: wakes the main loop for its watchdog */
}

static void timers_init(void)
{
    TCCR1A = 0;
    TCCR1B = _BV(CS11);                 /* prescaler 8 */
    TIMSK1 = _BV(TOIE1);
    TCCR2A = _BV(WGM21);                /* CTC */
    OCR2A = 249;                        /* 16 MHz / 64 / 250 = 1 kHz */
    TCCR2B = _BV(CS22);                 /* prescaler 64 */
    TIMSK2 = _BV(OCIE2A);
}

static acf_info_t info;
static uint16_t seq;                    /* of the last sample read */
static uint8_t last_count;              /* drdy_count when the last sample was handled */
static uint32_t good_t_us;              /* t_us of the last sample read */
static uint32_t drdy_seen_us;           /* t_us of the last data-ready, read or not */
static uint32_t last_recovery_us;
static uint32_t last_info_us;
static uint8_t after_recovery;          /* next sample: seq advances by the periods passed */
static uint8_t recovery_failed;         /* the last recovery could not configure the sensor */
static uint8_t silent_recoveries;       /* configured, but still no data-ready */

static void send_info(void)
{
    uint8_t frame[ACF_FRAME_MAX_SIZE];
    uint8_t n = ACF_FRAME_SIZE;
#if FW_FRAME_VERSION == 2
    acf_encode_info_v2(frame, &info);
    n = ACF_INFO_V2_SIZE;
#else
    acf_encode_info(frame, &info);
#endif
    while (uart_tx_free() < n)
        ;                               /* rare: wait for room rather than drop it */
    uart_write(frame, n);
    last_info_us = micros();
}

static void count_i2c_error(void)
{
    if (info.i2c_errors != 0xFFFFu)
        ++info.i2c_errors;
}

static uint8_t known_chip(uint8_t who)
{
    return who == 0x71 || who == 0x73 || who == 0x70 || who == 0x68;
}

static uint8_t cfg_status;

static void cfg_write(uint8_t reg, uint8_t value)
{
    if (cfg_status == TWI_OK)
        cfg_status = twi_write_reg(MPU_ADDR, reg, value);
}

/* Write the configuration and read it back; TWI_OK, a TWI error or CONFIG_MISMATCH.
 * full: device reset first (H_RESET, 100 ms); otherwise the registers are rewritten as
 * they are (about 0.5 ms of bus time). */
static uint8_t configure(uint8_t full)
{
    uint8_t back[4];
    uint8_t v;
    cfg_status = TWI_OK;
    if (full) {
        cfg_write(REG_PWR_MGMT_1, 0x80);                    /* device reset */
        _delay_ms(100);
    }
    cfg_write(REG_PWR_MGMT_1, 0x01);                        /* wake, PLL clock */
    if (full)
        _delay_ms(10);
    cfg_write(REG_PWR_MGMT_2, 0x00);                        /* all axes on */
    cfg_write(REG_SMPLRT_DIV, SMPLRT_DIV_VALUE);
    cfg_write(REG_CONFIG, FW_DLPF_CFG);
    cfg_write(REG_GYRO_CONFIG, FS_SEL << 3);                /* FCHOICE_B = 0 */
    cfg_write(REG_ACCEL_CONFIG, AFS_SEL << 3);
    if (info.who_am_i != 0x68)          /* 6500/9250/9255: accel DLPF, ACCEL_FCHOICE_B 0 */
        cfg_write(REG_ACCEL_CONFIG2, FW_DLPF_CFG);
    /* INT: active high, push-pull, 50 us pulse, cleared by reading INT_STATUS; bypass on,
     * so that the AK8963 of an MPU-9250 answers on this bus. */
    cfg_write(REG_INT_PIN_CFG, INT_PIN_CFG_VALUE);
    cfg_write(REG_INT_ENABLE, 0x01);                        /* data ready */
    if (cfg_status != TWI_OK)
        return cfg_status;
    if ((v = twi_read_regs(MPU_ADDR, REG_SMPLRT_DIV, back, 4)) != TWI_OK)
        return v;
    if (!(back[0] == SMPLRT_DIV_VALUE && (back[1] & 0x07) == FW_DLPF_CFG &&
          (back[2] & 0x1B) == (FS_SEL << 3) && (back[3] & 0x18) == (AFS_SEL << 3)))
        return CONFIG_MISMATCH;
    if ((v = twi_read_regs(MPU_ADDR, REG_INT_PIN_CFG, back, 2)) != TWI_OK)
        return v;                                           /* INT_PIN_CFG, INT_ENABLE */
    if ((v = twi_read_regs(MPU_ADDR, REG_PWR_MGMT_1, back + 2, 1)) != TWI_OK)
        return v;
    if (back[0] != INT_PIN_CFG_VALUE || !(back[1] & 0x01) || (back[2] & 0x40))
        return CONFIG_MISMATCH;                             /* no data-ready, or asleep */
    return TWI_OK;
}

/* The AK8963: probe, factory sensitivity adjustment (fuse ROM), 16-bit continuous mode 2.
 * Sets info.mag and info.asa. A chip without one (MPU-6500/6050) does not answer. */
static uint8_t mag_present;
static uint8_t mag_expected;            /* 9250/9255, or an AK8963 seen: probe on recovery */
static uint32_t mag_due_us;

static void mag_init(void)
{
    uint8_t who = 0;
    uint8_t mode = 0;
    mag_present = 0;
    info.mag = ACF_MAG_ABSENT;
    if (twi_read_regs(AK_ADDR, AK_WIA, &who, 1) != TWI_OK || who != AK_WIA_VALUE)
        return;
    info.mag = ACF_MAG_FAILED;
    if (twi_write_reg(AK_ADDR, AK_CNTL1, AK_MODE_POWER_DOWN) != TWI_OK)
        return;
    _delay_us(100);
    if (twi_write_reg(AK_ADDR, AK_CNTL1, AK_MODE_FUSE_ROM) != TWI_OK)
        return;
    _delay_us(100);
    if (twi_read_regs(AK_ADDR, AK_ASAX, info.asa, 3) != TWI_OK)
        return;
    if (twi_write_reg(AK_ADDR, AK_CNTL1, AK_MODE_POWER_DOWN) != TWI_OK)
        return;
    _delay_us(100);
    if (twi_write_reg(AK_ADDR, AK_CNTL1, AK_MODE_16BIT_CONT2) != TWI_OK ||
            twi_read_regs(AK_ADDR, AK_CNTL1, &mode, 1) != TWI_OK || mode != AK_MODE_16BIT_CONT2)
        return;
    info.mag = ACF_MAG_AK8963;
    mag_present = 1;
    mag_expected = 1;
    mag_due_us = micros();
}

/* Poll the AK8963 once its next sample is due: ST1, then HXL..HZH and ST2 (reading ST2
 * ends its read cycle). Return 1 with the 7 bytes HXL..ST2 in out when one was ready. */
static uint8_t mag_read(uint32_t t_us, uint8_t out[7])
{
    uint8_t buf[8];
    uint8_t i;
    if (!mag_present || (int32_t)(t_us - mag_due_us) < 0)
        return 0;
    if (twi_read_regs(AK_ADDR, AK_ST1, buf, 8) != TWI_OK) {
        count_i2c_error();
        mag_due_us = t_us + PERIOD_US;          /* try again with the next sample */
        return 0;
    }
    if (!(buf[0] & 0x01))
        return 0;                               /* not ready yet: look at the next sample */
    for (i = 0; i < 7; ++i)
        out[i] = buf[1 + i];
    mag_due_us = t_us + AK_PERIOD_US - AK_PERIOD_US / 10;
    return 1;
}

/* Find the sensor and configure it; return the info status. */
static uint8_t detect(void)
{
    uint8_t attempt;
    uint8_t who = 0;
    for (attempt = 0; attempt < 5; ++attempt) {
        if (twi_read_regs(MPU_ADDR, REG_WHO_AM_I, &who, 1) == TWI_OK) {
            info.who_am_i = who;
            if (!known_chip(who))
                return ACF_STATUS_UNKNOWN_CHIP;
            if (configure(1) != TWI_OK)
                return ACF_STATUS_CONFIG_FAILED;
            mag_expected = who == 0x71 || who == 0x73;  /* these contain an AK8963 */
            mag_init();
            return ACF_STATUS_STREAMING;
        }
        _delay_ms(20);
    }
    info.who_am_i = 0;
    return ACF_STATUS_NO_SENSOR;
}

static uint8_t cause_of(uint8_t st)
{
    if (twi_sda_low())
        return ACF_CAUSE_SDA_STUCK;
    return st == TWI_TIMEOUT ? ACF_CAUSE_TIMEOUT : ACF_CAUSE_NACK;
}

static void recover(uint8_t cause)
{
    uint8_t st;
    if (twi_sda_low())
        cause = ACF_CAUSE_SDA_STUCK;
    info.last_recovery = cause;
    if (info.recoveries != 0xFFFFu)
        ++info.recoveries;
    twi_bus_recover();
    if (cause == ACF_CAUSE_DRDY && !recovery_failed)
        ++silent_recoveries;
    st = configure(silent_recoveries > FULL_RESET_AFTER);
    /* The AK8963 may have lost its mode as well; a probe that failed during an earlier
     * recovery (the bus still disturbed) is tried again: absent is not for good. */
    if (st == TWI_OK && (info.mag != ACF_MAG_ABSENT || mag_expected))
        mag_init();
    if (st != TWI_OK) {
        count_i2c_error();
        if (st != CONFIG_MISMATCH)      /* the bus is the trouble, whatever noticed it */
            info.last_recovery = cause_of(st);
    } else if (silent_recoveries > FULL_RESET_AFTER) {
        silent_recoveries = 0;
    }
    recovery_failed = st != TWI_OK;
    after_recovery = 1;
    last_recovery_us = micros();
    send_info();
}

static void start_streaming(void)
{
    uint8_t status;
    twi_read_regs(MPU_ADDR, REG_INT_STATUS, &status, 1);     /* clear a stale flag */
    cli();
    last_count = drdy_count;
    sei();
    good_t_us = micros();
    drdy_seen_us = good_t_us;
    last_recovery_us = good_t_us;
    EICRA = _BV(ISC01) | _BV(ISC00);    /* INT0 on the rising edge */
    EIFR = _BV(INTF0);
    EIMSK = _BV(INT0);
}

static void handle_sample(uint8_t count, uint32_t t_us)
{
    uint8_t regs[14];
    uint8_t mag[7];
    uint8_t frame[ACF_FRAME_MAX_SIZE];
    uint8_t st, n, has_mag;
    uint16_t advance;
    drdy_seen_us = t_us;
    /* INT_STATUS first (clears the interrupt), then the 14-byte burst. */
    st = twi_read_regs(MPU_ADDR, REG_INT_STATUS, frame, 1);
    if (st == TWI_OK)
        st = twi_read_regs(MPU_ADDR, REG_ACCEL_XOUT_H, regs, 14);
    if (st != TWI_OK) {
        count_i2c_error();
        last_count = count;
        after_recovery = 1;             /* this sample is lost: count it by time */
        if (micros() - last_recovery_us >= RETRY_FAILED_US)
            recover(cause_of(st));
        return;
    }
    if (after_recovery) {               /* the periods that passed since the last sample */
        uint32_t periods = (t_us - good_t_us + PERIOD_US / 2) / PERIOD_US;
        advance = periods == 0 ? 1u : (periods > 0xFFFFu ? 0xFFFFu : (uint16_t)periods);
        after_recovery = 0;
    } else {
        advance = (uint8_t)(count - last_count);
    }
    last_count = count;
    seq = (uint16_t)(seq + advance);
    good_t_us = t_us;
    silent_recoveries = 0;
    has_mag = mag_read(t_us, mag);      /* sent with the sensor sample read with it */
#if FW_FRAME_VERSION == 2
    n = acf_encode_data_v2(frame, seq, t_us, regs, has_mag ? mag : 0);
#else
    (void)has_mag;                      /* version 1 has no room for it */
    acf_encode_data(frame, (uint8_t)seq, t_us, regs);
    n = ACF_FRAME_SIZE;
#endif
    if (uart_tx_free() >= n)
        uart_write(frame, n);
}

int main(void)
{
    timers_init();
    uart_init(FW_BAUD);
    twi_init();
    sei();
    _delay_ms(100);                     /* sensor start-up time */

    info.accel_range_g = FW_ACCEL_RANGE_G;
    info.gyro_range_dps = FW_GYRO_RANGE_DPS;
    info.rate_hz = FW_RATE_HZ;
    info.dlpf_cfg = FW_DLPF_CFG;
    info.baud = FW_BAUD;
    info.fw_major = FW_MAJOR;
    info.fw_minor = FW_MINOR;
    info.frame_version = FW_FRAME_VERSION;
    info.status = detect();
    send_info();
    if (info.status == ACF_STATUS_STREAMING)
        start_streaming();

    for (;;) {
        uint8_t count;
        uint32_t t_us, now;
        cli();
        count = drdy_count;
        t_us = drdy_t_us;
        if (count == last_count && !uart_request_pending() && !tick) {
            set_sleep_mode(SLEEP_MODE_IDLE);   /* UART and timers keep running */
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
            continue;
        }
        tick = 0;
        sei();
        if (uart_take_request())
            send_info();
        if (info.status != ACF_STATUS_STREAMING) {
            /* Report, never stream as if it were a known chip; look for the sensor again. */
            if (micros() - last_info_us >= INFO_EVERY_US) {
                info.status = detect();
                send_info();
                if (info.status == ACF_STATUS_STREAMING)
                    start_streaming();
            }
            continue;
        }
        if (count != last_count) {
            handle_sample(count, t_us);
            continue;
        }
        now = micros();
        if (now - drdy_seen_us > DRDY_TIMEOUT_US &&
                now - last_recovery_us > (recovery_failed ? RETRY_FAILED_US : DRDY_TIMEOUT_US))
            recover(ACF_CAUSE_DRDY);
        else if (now - last_info_us >= INFO_EVERY_US)
            send_info();
    }
}
