/*
 * mpu_board: an emulated Arduino Uno (ATmega328P, 16 MHz, simavr) with an emulated
 * InvenSense MPU-9250-class sensor on its TWI bus, for hardware-in-the-loop tests.
 *
 * Copyright (C) 2026 accel_calib_ros contributors.
 *
 * This program is free software: you can redistribute it and/or modify it under the
 * terms of the GNU General Public License as published by the Free Software Foundation,
 * either version 3 of the License, or (at your option) any later version. It links
 * libsimavr (GPL-3), so it is a separate test program: it is built only by the tests
 * and never installed with the accel_calib_ros package.
 *
 * This program is distributed in the hope that it will be useful, but WITHOUT ANY
 * WARRANTY; without even the implied warranty of MERCHANTABILITY or FITNESS FOR A
 * PARTICULAR PURPOSE. See the GNU General Public License for more details:
 * <https://www.gnu.org/licenses/>.
 *
 * The sensor model follows the register map: WHO_AM_I, reset state (DLPF_CFG 0 means an
 * internal rate of 8 kHz; the MPU-6050 wakes up asleep), H_RESET, SMPLRT_DIV, CONFIG,
 * PWR_MGMT_1 sleep, INT_PIN_CFG (active level, latch, any-read clear), INT_ENABLE, and
 * INT_STATUS (clears on read). Each sample writes seven big-endian counts to 0x3B..0x48,
 * sets DATA_RDY_INT and drives INT (on PD2 = INT0). The UART goes to a pty (symlink
 * --link) or a file. simavr 1.6 quirks are repaired here: TWINT is made to clear when
 * written with 1, and the status after SLA+W reads 0x18/0x20 (not 0x28/0x30).
 *
 * The MPU-9250/9255 carries an AK8963 magnetometer (address 0x0C, reachable once the
 * firmware sets INT_PIN_CFG.BYPASS_EN): WIA 0x48, ST1 (DRDY, DOR), HXL..HZH little-endian,
 * ST2 (HOFL, BITM; reading it ends the read cycle and clears DRDY), CNTL1 (mode, BIT),
 * CNTL2 (SRST) and the fuse ROM ASA values (readable in fuse ROM access mode only). In
 * continuous mode 2 it measures every 10 ms a field that wanders slowly (random walk), or
 * with --mag-samples FILE the rows of FILE (hx hy hz, int16 in the AK8963's axes, one per
 * 10 ms of the --samples script: the field of the pose held), and with
 * --mag-hofl-every N an overflow (HOFL) every Nth measurement. Its measurements are
 * logged with --mag-log FILE ("index t_us hx hy hz st2"). --mag none removes it; the
 * MPU-6500/6050 (--who 0x70/0x68) have none.
 *
 * Faults (--fault KIND:START_MS[:DURATION_MS], up to 8, simulated milliseconds):
 *   int-silent  the sensor keeps sampling but does not drive INT for the duration;
 *   brownout    the sensor's registers fall back to their power-on state (INT_ENABLE 0,
 *               DLPF 0, ...): INT stays silent until the firmware configures it again;
 *   nack        the sensor does not acknowledge any I2C transfer for the duration;
 *   sda-stuck   the sensor holds SDA low (PC4 reads 0, transfers fail) for the duration
 *               and lets it go only at an SCL pulse after that (a slave stuck in a byte:
 *               only a bus recovery that clocks SCL by hand frees it);
 *   ak-nack     the AK8963 alone does not acknowledge for the duration (the MPU does).
 * The I2C pins have the board's external pull-ups (PC4 and PC5 read 1 when released); SCL
 * pulses clocked by hand (PORTC/DDRC, TWI off) are counted.
 *
 * Usage: mpu_board --elf FW.elf [--link PATH | --uart-out FILE] [--seconds S]
 *        [--who 0x71 | --who none] [--seed N] [--samples FILE] [--log FILE] [--fast]
 *        [--wait-open S]   (start the board only once the pty is opened, S s at most)
 *        [--raw-twi]       (keep simavr 1.6's TWI quirks, to check the firmware copes)
 *        [--fault KIND:START_MS[:DURATION_MS]]... [--mag none] [--asa X,Y,Z]
 *        [--mag-log FILE] [--mag-hofl-every N] [--mag-samples FILE]
 * On exit (after S simulated seconds, or SIGINT/SIGTERM) one JSON line on stdout reports
 * what the firmware configured and how much it sent, the faults and the SCL pulses.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <simavr/avr_ioport.h>
#include <simavr/avr_twi.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_time.h>

#define F_CPU_HZ 16000000u
#define MPU_ADDR 0x68
#define AK_ADDR 0x0C
/* ATmega328P data addresses */
#define A_TWBR 0xB8
#define A_TWSR 0xB9
#define A_TWCR 0xBC
#define A_UCSR0A 0xC0
#define A_UBRR0L 0xC4
#define A_UBRR0H 0xC5
#define TWINT_BIT 0x80
#define A_PINC 0x26
#define A_DDRC 0x27
#define A_PORTC 0x28
#define MAX_FAULTS 8

static avr_t *avr;
static int raw_twi;               /* --raw-twi: keep simavr 1.6's TWI quirks */
static volatile sig_atomic_t stop_requested;

/* ---- sensor model -------------------------------------------------------------- */
static uint8_t reg[128];
static int who = 0x71;            /* -1: no device answers at 0x68 */
static int selected, reg_index_pending, ptr;
static int selected_ak;
static int addr_phase_write;      /* the last TWI byte sent was SLA+W */
static avr_irq_t *twi_in, *int_pin;
static int pin_level;
static uint64_t samples_made, int_status_reads, twi_writes, bursts_0x3b;
static uint64_t seed_state = 88172645463325252ull;
static int16_t *script;
static size_t script_rows;
static int16_t temp_count;
static FILE *log_file;
static avr_cycle_count_t sample_cycles;
static uint32_t last_rate_hz;

/* ---- faults -------------------------------------------------------------------- */
enum { F_INT_SILENT, F_BROWNOUT, F_NACK, F_SDA_STUCK, F_AK_NACK, N_FAULT_KINDS };
static const char *fault_names[] = {"int-silent", "brownout", "nack", "sda-stuck", "ak-nack"};
typedef struct {
    int kind;
    uint64_t start_us, end_us;          /* simulated µs */
    uint64_t released_us;               /* sda-stuck: when SDA went high again (0: not yet) */
    int active;
} fault_t;
static fault_t faults[MAX_FAULTS];
static int n_faults;
static avr_irq_t *sda_pin, *scl_pin;
static int scl_level = 1;
static uint64_t scl_pulses, scl_pulses_in_faults;

static uint64_t now_us(void) { return avr->cycle / (F_CPU_HZ / 1000000u); }

static int fault_active(int kind)
{
    int i;
    for (i = 0; i < n_faults; ++i)
        if (faults[i].kind == kind && faults[i].active)
            return 1;
    return 0;
}

static avr_cycle_count_t fault_start(avr_t *a, avr_cycle_count_t when, void *param);
static avr_cycle_count_t fault_end(avr_t *a, avr_cycle_count_t when, void *param);

static uint64_t xorshift(void)
{
    seed_state ^= seed_state << 13;
    seed_state ^= seed_state >> 7;
    seed_state ^= seed_state << 17;
    return seed_state;
}

static void sensor_reset(void)
{
    memset(reg, 0, sizeof reg);
    reg[0x6B] = (who == 0x68) ? 0x40 : 0x01;   /* 6050 wakes up asleep */
    reg[0x75] = (uint8_t)(who < 0 ? 0 : who);
}

static int active_level(void) { return (reg[0x37] & 0x80) ? 0 : 1; }

static void set_pin(int asserted)
{
    int level = asserted ? active_level() : !active_level();
    if (level != pin_level) {
        pin_level = level;
        avr_raise_irq(int_pin, level);
    }
}

static void clear_int(void)
{
    reg[0x3A] &= (uint8_t)~0x01;
    if (reg[0x37] & 0x20)           /* latched: released when cleared */
        set_pin(0);
}

static uint8_t sensor_read(void)
{
    uint8_t r = (uint8_t)(ptr & 0x7F);
    uint8_t v = reg[r];
    if (r == 0x3A) {
        ++int_status_reads;
        clear_int();
    } else if (reg[0x37] & 0x10) {  /* INT_ANYRD_2CLEAR */
        clear_int();
    }
    ptr = (ptr + 1) & 0x7F;
    return v;
}

static void sensor_write(uint8_t value)
{
    uint8_t r = (uint8_t)(ptr & 0x7F);
    ++twi_writes;
    if (r == 0x6B && (value & 0x80)) {
        sensor_reset();
    } else if (r != 0x75 && r != 0x3A && !(r >= 0x3B && r <= 0x60)) {
        reg[r] = value;
    }
    ptr = (ptr + 1) & 0x7F;
}

/* ---- AK8963 model ----------------------------------------------------------------- */
static int ak_present = 1;
static uint8_t ak_reg[0x13];
static uint8_t ak_asa[3] = {176, 177, 165};
static int ak_ptr, ak_index_pending;
static int16_t ak_field[3] = {120, -240, 310};   /* counts, about 18, -36, 46 uT */
static uint64_t mag_samples;
static int16_t *mag_script;                     /* --mag-samples: hx hy hz per 10 ms */
static size_t mag_rows;
static unsigned mag_hofl_every;
static FILE *mag_log;

static void ak_reset(void)
{
    memset(ak_reg, 0, sizeof ak_reg);
    ak_reg[0x00] = 0x48;                        /* WIA */
    ak_reg[0x01] = 0x9A;                        /* INFO */
}

static int ak_visible(void)
{
    return ak_present && (reg[0x37] & 0x02);    /* behind the MPU's bypass switch */
}

static uint8_t ak_read(void)
{
    uint8_t r = (uint8_t)ak_ptr;
    uint8_t v = 0;
    if (r < sizeof ak_reg)
        v = ak_reg[r];
    if (r >= 0x10 && r <= 0x12)                 /* fuse ROM: only in fuse access mode */
        v = (ak_reg[0x0A] & 0x0F) == 0x0F ? ak_asa[r - 0x10] : 0;
    if (r == 0x09)                              /* ST2 read: the read cycle is over */
        ak_reg[0x02] &= (uint8_t)~0x03;
    ak_ptr = (ak_ptr + 1) % 0x13;
    return v;
}

static void ak_write(uint8_t value)
{
    uint8_t r = (uint8_t)ak_ptr;
    if (r == 0x0A)
        ak_reg[0x0A] = value & 0x1F;
    else if (r == 0x0B && (value & 0x01))
        ak_reset();                             /* CNTL2.SRST */
    else if (r == 0x0C)
        ak_reg[0x0C] = value & 0x40;
    ak_ptr = (ak_ptr + 1) % 0x13;
}

static avr_cycle_count_t ak_tick(avr_t *a, avr_cycle_count_t when, void *param)
{
    int i;
    int16_t h[3];
    uint8_t st2;
    (void)param;
    if (ak_present && (ak_reg[0x0A] & 0x0F) == 0x06) {      /* continuous mode 2, 100 Hz */
        for (i = 0; i < 3; ++i) {
            if (mag_script)     /* the field of the pose the accelerometer script holds now */
                ak_field[i] = mag_script[3 * ((samples_made / 10u) % mag_rows) + i];
            else
                ak_field[i] = (int16_t)(ak_field[i] + (int)(xorshift() % 41) - 20);
            h[i] = ak_field[i];
        }
        st2 = (ak_reg[0x0A] & 0x10) ? 0x10 : 0x00;           /* BITM follows CNTL1.BIT */
        if (mag_hofl_every && (mag_samples + 1) % mag_hofl_every == 0)
            st2 |= 0x08;                                     /* HOFL */
        for (i = 0; i < 3; ++i) {
            ak_reg[0x03 + 2 * i] = (uint8_t)((uint16_t)h[i] & 0xFF);
            ak_reg[0x04 + 2 * i] = (uint8_t)((uint16_t)h[i] >> 8);
        }
        ak_reg[0x09] = st2;
        if (ak_reg[0x02] & 0x01)
            ak_reg[0x02] |= 0x02;                            /* DOR: the last was not read */
        ak_reg[0x02] |= 0x01;                                /* DRDY */
        if (mag_log)
            fprintf(mag_log, "%llu %llu %d %d %d %u\n", (unsigned long long)mag_samples,
                    (unsigned long long)(a->cycle / (F_CPU_HZ / 1000000u)), h[0], h[1], h[2],
                    st2);
        ++mag_samples;
    }
    return when + F_CPU_HZ / 100u;
}

/* Internal rate 1 kHz when 0 < DLPF_CFG < 7 (and FCHOICE_B = 0), else 8 kHz. */
static uint32_t sample_rate_hz(void)
{
    uint8_t dlpf = reg[0x1A] & 0x07;
    uint32_t internal = (dlpf >= 1 && dlpf <= 6 && (reg[0x1B] & 0x03) == 0) ? 1000u : 8000u;
    return internal / (1u + reg[0x19]);
}

static avr_cycle_count_t pulse_end(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    if (!(reg[0x37] & 0x20))
        set_pin(0);
    return 0;
}

static avr_cycle_count_t sample_tick(avr_t *a, avr_cycle_count_t when, void *param)
{
    int16_t c[7];
    int i;
    (void)param;
    if (who < 0 || (reg[0x6B] & 0x40)) {        /* no sensor or asleep: look again in 1 ms */
        last_rate_hz = 0;
        return when + F_CPU_HZ / 1000u;
    }
    last_rate_hz = sample_rate_hz();
    if (script) {
        const int16_t *row = script + 7 * (samples_made % script_rows);
        for (i = 0; i < 7; ++i)
            c[i] = row[i];
    } else {
        for (i = 0; i < 7; ++i)
            c[i] = (int16_t)(xorshift() & 0xFFFF);
        temp_count = (int16_t)(temp_count + (int)(xorshift() % 7) - 3);
        c[3] = temp_count;
    }
    for (i = 0; i < 7; ++i) {
        reg[0x3B + 2 * i] = (uint8_t)((uint16_t)c[i] >> 8);
        reg[0x3C + 2 * i] = (uint8_t)((uint16_t)c[i] & 0xFF);
    }
    if (log_file)
        fprintf(log_file, "%llu %llu %d %d %d %d %d %d %d\n",
                (unsigned long long)samples_made,
                (unsigned long long)(a->cycle / (F_CPU_HZ / 1000000u)),
                c[0], c[1], c[2], c[3], c[4], c[5], c[6]);
    ++samples_made;
    reg[0x3A] |= 0x01;
    if ((reg[0x38] & 0x01) && !fault_active(F_INT_SILENT)) {
        set_pin(1);
        if (!(reg[0x37] & 0x20))
            avr_cycle_timer_register_usec(a, 50, pulse_end, NULL);
    }
    sample_cycles = F_CPU_HZ / last_rate_hz;
    return when + sample_cycles;
}

/* TWI slave side: messages from the master (simavr's TWI_IRQ_OUTPUT). */
static void twi_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    avr_twi_msg_irq_t m;
    (void)irq; (void)param;
    m.u.v = value;
    if (m.u.twi.msg & TWI_COND_STOP)
        selected = selected_ak = 0;
    if (m.u.twi.msg & TWI_COND_START) {
        selected = selected_ak = 0;
        addr_phase_write = !(m.u.twi.addr & 1);
        if (fault_active(F_NACK) || fault_active(F_SDA_STUCK))
            return;                                 /* nobody acknowledges */
        if ((m.u.twi.addr >> 1) == AK_ADDR && ak_visible() && !fault_active(F_AK_NACK)) {
            selected = selected_ak = m.u.twi.addr;
            ak_index_pending = !(m.u.twi.addr & 1);
            avr_raise_irq(twi_in, avr_twi_irq_msg(TWI_COND_ACK, selected, 1));
            return;
        }
        if (who >= 0 && (m.u.twi.addr >> 1) == MPU_ADDR) {
            selected = m.u.twi.addr;
            reg_index_pending = !(m.u.twi.addr & 1);
            if ((m.u.twi.addr & 1) && ptr == 0x3B)
                ++bursts_0x3b;
            avr_raise_irq(twi_in, avr_twi_irq_msg(TWI_COND_ACK, selected, 1));
        }
        return;
    }
    if (!selected)
        return;
    if (selected_ak) {
        if (m.u.twi.msg & TWI_COND_WRITE) {
            addr_phase_write = 0;
            avr_raise_irq(twi_in, avr_twi_irq_msg(TWI_COND_ACK, selected, 1));
            if (ak_index_pending) {
                ak_ptr = m.u.twi.data % 0x13;
                ak_index_pending = 0;
            } else {
                ak_write(m.u.twi.data);
            }
        }
        if (m.u.twi.msg & TWI_COND_READ)
            avr_raise_irq(twi_in, avr_twi_irq_msg(TWI_COND_READ, selected, ak_read()));
        return;
    }
    if (m.u.twi.msg & TWI_COND_WRITE) {
        addr_phase_write = 0;
        avr_raise_irq(twi_in, avr_twi_irq_msg(TWI_COND_ACK, selected, 1));
        if (reg_index_pending) {
            ptr = m.u.twi.data & 0x7F;
            reg_index_pending = 0;
        } else {
            sensor_write(m.u.twi.data);
        }
    }
    if (m.u.twi.msg & TWI_COND_READ)
        avr_raise_irq(twi_in, avr_twi_irq_msg(TWI_COND_READ, selected, sensor_read()));
}

/* simavr 1.6: the status after SLA+W comes out as 0x28/0x30; silicon says 0x18/0x20. */
static void twi_status_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (raw_twi)
        return;
    if (addr_phase_write && (value == 0x28 || value == 0x30)) {
        avr->data[A_TWSR] = (uint8_t)((avr->data[A_TWSR] & 0x07) | (value == 0x28 ? 0x18 : 0x20));
        addr_phase_write = 0;
    }
}

/* simavr 1.6: TWINT is sticky; writing 1 to it must clear it until the operation ends. */
static void twcr_write_hook(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)param;
    if (!raw_twi && (v & TWINT_BIT))
        a->data[addr] &= (uint8_t)~TWINT_BIT;
}

static avr_cycle_count_t fault_start(avr_t *a, avr_cycle_count_t when, void *param)
{
    fault_t *f = param;
    (void)a; (void)when;
    f->active = 1;
    if (f->kind == F_BROWNOUT) {
        sensor_reset();                         /* power-on register values */
        set_pin(0);
        f->active = 0;
    } else if (f->kind == F_SDA_STUCK) {
        avr_raise_irq(sda_pin, 0);
    }
    if (f->kind != F_BROWNOUT && f->end_us > f->start_us)
        avr_cycle_timer_register_usec(avr, (uint32_t)(f->end_us - f->start_us), fault_end, f);
    return 0;
}

static avr_cycle_count_t fault_end(avr_t *a, avr_cycle_count_t when, void *param)
{
    fault_t *f = param;
    (void)a; (void)when;
    if (f->kind != F_SDA_STUCK)                 /* SDA: released by the next SCL pulse */
        f->active = 0;
    return 0;
}

/* SCL clocked by hand (TWI off): open drain, so high unless driven low as an output. */
static void portc_watch(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    uint8_t ddr = addr == A_DDRC ? v : a->data[A_DDRC];
    uint8_t port = addr == A_PORTC ? v : a->data[A_PORTC];
    int level = (ddr & 0x20) ? ((port >> 5) & 1) : 1;
    int i;
    (void)param;
    if (level && !scl_level) {                  /* a pulse completed */
        ++scl_pulses;
        for (i = 0; i < n_faults; ++i) {
            fault_t *f = &faults[i];
            if (f->kind != F_SDA_STUCK || !f->active)
                continue;
            ++scl_pulses_in_faults;
            if (now_us() >= f->end_us) {        /* the stuck slave finished its byte */
                f->active = 0;
                f->released_us = now_us();
                avr_raise_irq(sda_pin, 1);
            }
        }
    }
    scl_level = level;
    if (fault_active(F_SDA_STUCK))              /* the slave wins over the pull-up */
        avr_raise_irq(sda_pin, 0);
}

static int parse_fault(const char *text)
{
    char name[32];
    double start_ms = 0, dur_ms = 0;
    int k, got;
    fault_t *f;
    if (n_faults == MAX_FAULTS)
        return 0;
    got = sscanf(text, "%31[a-z-]:%lf:%lf", name, &start_ms, &dur_ms);
    if (got < 2 || start_ms < 0 || dur_ms < 0)
        return 0;
    for (k = 0; k < N_FAULT_KINDS && strcmp(name, fault_names[k]); ++k)
        ;
    if (k == N_FAULT_KINDS || (k != F_BROWNOUT && got < 3))
        return 0;
    f = &faults[n_faults++];
    f->kind = k;
    f->start_us = (uint64_t)(start_ms * 1000.0);
    f->end_us = f->start_us + (uint64_t)(dur_ms * 1000.0);
    return 1;
}

/* ---- UART <-> pty or file ------------------------------------------------------- */
static int out_fd = -1, in_fd = -1, slave_keep = -1;
static uint8_t *obuf;
static size_t olen, ocap = 1u << 22;
static uint64_t uart_bytes, uart_dropped;
static avr_irq_t *uart_in;

static void uart_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    ++uart_bytes;
    if (olen < ocap)
        obuf[olen++] = (uint8_t)value;
    else
        ++uart_dropped;
}

static void flush_out(void)
{
    size_t done = 0;
    while (done < olen) {
        ssize_t n = write(out_fd, obuf + done, olen - done);
        if (n <= 0)
            break;
        done += (size_t)n;
    }
    if (done) {
        memmove(obuf, obuf + done, olen - done);
        olen -= done;
    }
}

static void poll_in(void)
{
    uint8_t b[64];
    ssize_t n, i;
    if (in_fd < 0)
        return;
    n = read(in_fd, b, sizeof b);
    for (i = 0; i < n; ++i)
        avr_raise_irq(uart_in, b[i]);
}

static void no_sleep(avr_t *a, avr_cycle_count_t how_long)
{
    (void)a; (void)how_long;
}

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

static uint64_t wall_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

static int open_pty(const char *link, int keep_slave)
{
    int m = posix_openpt(O_RDWR | O_NOCTTY);
    struct termios t;
    if (m < 0 || grantpt(m) || unlockpt(m))
        return -1;
    /* Open the slave once: keeping it open keeps the pty alive; closing it again makes
     * the master report POLLHUP until the driver opens it (see --wait-open). */
    slave_keep = open(ptsname(m), O_RDWR | O_NOCTTY);
    if (slave_keep < 0)
        return -1;
    if (!keep_slave) {
        close(slave_keep);
        slave_keep = -1;
    }
    tcgetattr(m, &t);
    cfmakeraw(&t);
    tcsetattr(m, TCSANOW, &t);
    unlink(link);
    if (symlink(ptsname(m), link))
        return -1;
    fcntl(m, F_SETFL, O_NONBLOCK);
    return m;
}

int main(int argc, char **argv)
{
    const char *elf = NULL, *link = NULL, *uart_out = NULL, *samples = NULL, *log_path = NULL;
    double seconds = 5.0, wait_open = 0.0;
    int fast = 0, i, state = cpu_Running;
    elf_firmware_t fw;
    uint64_t t0, next_service, end_cycle;

    for (i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = (i + 1 < argc) ? argv[i + 1] : NULL;
        if (!strcmp(a, "--fast")) { fast = 1; continue; }
        if (!strcmp(a, "--raw-twi")) { raw_twi = 1; continue; }
        if (!v) { fprintf(stderr, "mpu_board: %s needs a value\n", a); return 2; }
        ++i;
        if (!strcmp(a, "--elf")) elf = v;
        else if (!strcmp(a, "--link")) link = v;
        else if (!strcmp(a, "--uart-out")) uart_out = v;
        else if (!strcmp(a, "--seconds")) seconds = atof(v);
        else if (!strcmp(a, "--who")) who = strcmp(v, "none") ? (int)strtol(v, NULL, 0) : -1;
        else if (!strcmp(a, "--seed")) seed_state ^= strtoull(v, NULL, 0) * 0x9E3779B97F4A7C15ull;
        else if (!strcmp(a, "--samples")) samples = v;
        else if (!strcmp(a, "--log")) log_path = v;
        else if (!strcmp(a, "--wait-open")) wait_open = atof(v);
        else if (!strcmp(a, "--mag")) ak_present = strcmp(v, "none") != 0;
        else if (!strcmp(a, "--mag-log")) {
            if (!(mag_log = fopen(v, "w"))) { perror(v); return 2; }
        }
        else if (!strcmp(a, "--mag-hofl-every")) mag_hofl_every = (unsigned)atoi(v);
        else if (!strcmp(a, "--mag-samples")) {
            FILE *f = fopen(v, "rb");
            long size;
            if (!f) { perror(v); return 2; }
            fseek(f, 0, SEEK_END);
            size = ftell(f);
            rewind(f);
            mag_rows = (size_t)size / 6u;
            mag_script = malloc(mag_rows * 6u + 6u);
            if (!mag_rows || fread(mag_script, 6, mag_rows, f) != mag_rows) {
                fprintf(stderr, "mpu_board: %s: expected rows of 3 int16\n", v);
                return 2;
            }
            fclose(f);
        }
        else if (!strcmp(a, "--asa")) {
            unsigned x, y, z;
            if (sscanf(v, "%u,%u,%u", &x, &y, &z) != 3 || x > 255 || y > 255 || z > 255) {
                fprintf(stderr, "mpu_board: bad --asa %s (X,Y,Z, 0..255 each)\n", v);
                return 2;
            }
            ak_asa[0] = (uint8_t)x; ak_asa[1] = (uint8_t)y; ak_asa[2] = (uint8_t)z;
        }
        else if (!strcmp(a, "--fault")) {
            if (!parse_fault(v)) {
                fprintf(stderr, "mpu_board: bad --fault %s (KIND:START_MS[:DURATION_MS], KIND "
                        "int-silent brownout nack sda-stuck, at most %d)\n", v, MAX_FAULTS);
                return 2;
            }
        }
        else { fprintf(stderr, "mpu_board: unknown option %s\n", a); return 2; }
    }
    if (!elf || (!link && !uart_out) || !(seconds > 0)) {
        fprintf(stderr, "usage: mpu_board --elf FW.elf (--link PATH | --uart-out FILE) "
                "[--seconds S] [--who 0x71|none] [--seed N] [--samples FILE] [--log FILE] "
                "[--fast] [--fault KIND:START_MS[:DURATION_MS]]...\n");
        return 2;
    }
    if (samples) {
        FILE *f = fopen(samples, "rb");
        long size;
        if (!f) { perror(samples); return 2; }
        fseek(f, 0, SEEK_END);
        size = ftell(f);
        rewind(f);
        script_rows = (size_t)size / 14u;
        script = malloc(script_rows * 14u + 14u);
        if (!script_rows || fread(script, 14, script_rows, f) != script_rows) {
            fprintf(stderr, "mpu_board: %s: expected rows of 7 int16\n", samples);
            return 2;
        }
        fclose(f);
    }
    temp_count = (int16_t)(who == 0x68 ? -3920 : 1335);     /* about 25 degC */
    if (who != 0x71 && who != 0x73)
        ak_present = 0;                                     /* MPU-6500/6050: no AK8963 */
    ak_reset();
    if (log_path && !(log_file = fopen(log_path, "w"))) { perror(log_path); return 2; }
    obuf = malloc(ocap);

    if (elf_read_firmware(elf, &fw)) { fprintf(stderr, "mpu_board: cannot read %s\n", elf); return 2; }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) { fprintf(stderr, "mpu_board: no atmega328p core\n"); return 2; }
    avr_init(avr);
    avr->log = LOG_ERROR;
    fw.frequency = F_CPU_HZ;
    avr_load_firmware(avr, &fw);
    avr->frequency = F_CPU_HZ;
    avr->sleep = no_sleep;

    {   /* UART: no poll-sleep, no stdio echo; output to our buffer */
        uint32_t flags = 0;
        avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
        flags &= ~(uint32_t)(AVR_UART_FLAG_POLL_SLEEP | AVR_UART_FLAG_STDIO);
        avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                                uart_hook, NULL);
        uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    }
    twi_in = avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT),
                            twi_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_STATUS),
                            twi_status_hook, NULL);
    avr_register_io_write(avr, A_TWCR, twcr_write_hook, NULL);
    int_pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    sda_pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('C'), 4);
    scl_pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('C'), 5);
    avr_raise_irq(sda_pin, 1);                  /* the board's pull-ups */
    avr_raise_irq(scl_pin, 1);
    avr_register_io_write(avr, A_DDRC, portc_watch, NULL);
    avr_register_io_write(avr, A_PORTC, portc_watch, NULL);
    for (i = 0; i < n_faults; ++i)
        avr_cycle_timer_register_usec(avr, (uint32_t)(faults[i].start_us ? faults[i].start_us : 1),
                                      fault_start, &faults[i]);
    sensor_reset();
    pin_level = !active_level();
    avr_raise_irq(int_pin, pin_level);
    avr_cycle_timer_register_usec(avr, 1000, sample_tick, NULL);
    avr_cycle_timer_register_usec(avr, 10000, ak_tick, NULL);

    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    if (link) {
        out_fd = in_fd = open_pty(link, !(wait_open > 0));
        if (out_fd < 0) { perror("mpu_board: pty"); return 2; }
        if (wait_open > 0) {    /* power the board up when the driver opens the port */
            uint64_t deadline = wall_ns() + (uint64_t)(wait_open * 1e9);
            for (;;) {
                struct pollfd pfd = {out_fd, POLLIN, 0};
                poll(&pfd, 1, 0);
                if (!(pfd.revents & POLLHUP) || wall_ns() > deadline || stop_requested)
                    break;
                usleep(2000);
            }
        }
    } else {
        out_fd = open(uart_out, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (out_fd < 0) { perror(uart_out); return 2; }
    }

    end_cycle = (avr_cycle_count_t)(seconds * F_CPU_HZ);
    next_service = F_CPU_HZ / 1000u;
    t0 = wall_ns();                     /* after --wait-open: simulated time starts now */
    while (!stop_requested && avr->cycle < end_cycle) {
        state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed)
            break;
        if (avr->cycle >= next_service) {
            next_service = avr->cycle + F_CPU_HZ / 1000u;
            flush_out();
            poll_in();
            if (!fast) {
                uint64_t sim_ns = avr->cycle * (1000000000ull / F_CPU_HZ) / 1ull;
                uint64_t now = wall_ns() - t0;
                if (sim_ns > now + 1000000ull) {
                    struct timespec ts = {0, (long)(sim_ns - now)};
                    nanosleep(&ts, NULL);
                }
            }
        }
    }
    flush_out();
    {
        double sim_s = (double)avr->cycle / F_CPU_HZ;
        double wall_s = (double)(wall_ns() - t0) * 1e-9;
        unsigned ubrr = avr->data[A_UBRR0L] | ((unsigned)avr->data[A_UBRR0H] << 8);
        int u2x = (avr->data[A_UCSR0A] & 0x02) != 0;
        double baud = (double)F_CPU_HZ / ((u2x ? 8.0 : 16.0) * (ubrr + 1));
        unsigned twbr = avr->data[A_TWBR], twps = avr->data[A_TWSR] & 0x03;
        double scl = (double)F_CPU_HZ / (16.0 + 2.0 * twbr * (1u << (2 * twps)));
        printf("{\"state\": \"%s\", \"sim_seconds\": %.6f, \"wall_seconds\": %.3f, "
               "\"samples\": %llu, \"sample_rate_hz\": %u, \"uart_bytes\": %llu, "
               "\"uart_dropped\": %llu, \"pending_out\": %zu, \"baud\": %.1f, \"ubrr\": %u, "
               "\"u2x\": %d, \"scl_hz\": %.1f, \"int_status_reads\": %llu, "
               "\"bursts_from_0x3b\": %llu, \"twi_register_writes\": %llu, "
               "\"who_am_i\": %d, \"SMPLRT_DIV\": %u, \"CONFIG\": %u, \"GYRO_CONFIG\": %u, "
               "\"ACCEL_CONFIG\": %u, \"ACCEL_CONFIG2\": %u, \"INT_PIN_CFG\": %u, "
               "\"INT_ENABLE\": %u, \"PWR_MGMT_1\": %u, \"scl_pulses\": %llu, "
               "\"scl_pulses_in_faults\": %llu, \"ak_present\": %d, \"ak_cntl1\": %u, "
               "\"mag_samples\": %llu, \"faults\": [",
               state == cpu_Crashed ? "crashed" : (state == cpu_Done ? "done" : "running"),
               sim_s, wall_s, (unsigned long long)samples_made, last_rate_hz,
               (unsigned long long)uart_bytes, (unsigned long long)uart_dropped, olen, baud,
               ubrr, u2x, scl, (unsigned long long)int_status_reads,
               (unsigned long long)bursts_0x3b, (unsigned long long)twi_writes, who,
               reg[0x19], reg[0x1A], reg[0x1B], reg[0x1C], reg[0x1D], reg[0x37], reg[0x38],
               reg[0x6B], (unsigned long long)scl_pulses,
               (unsigned long long)scl_pulses_in_faults, ak_present, ak_reg[0x0A],
               (unsigned long long)mag_samples);
        for (i = 0; i < n_faults; ++i)
            printf("%s{\"kind\": \"%s\", \"start_us\": %llu, \"end_us\": %llu, "
                   "\"released_us\": %llu, \"active\": %d}", i ? ", " : "",
                   fault_names[faults[i].kind], (unsigned long long)faults[i].start_us,
                   (unsigned long long)faults[i].end_us,
                   (unsigned long long)faults[i].released_us, faults[i].active);
        printf("]}\n");
    }
    if (log_file)
        fclose(log_file);
    if (mag_log)
        fclose(mag_log);
    if (link)
        unlink(link);
    return state == cpu_Crashed ? 1 : 0;
}
