/*
 * accel_calib_fw: UART0, 8N1, double speed (U2X): UBRR = F_CPU / (8 * baud) - 1, rounded.
 * 1 000 000 and 500 000 baud are exact at 16 MHz; 115200 is off by 2.1 %.
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#include <avr/interrupt.h>
#include <avr/io.h>

#include "uart.h"

#define TX_SIZE 256u  /* uint8_t indices wrap by themselves */

static uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head;
static volatile uint8_t tx_tail;
static volatile uint8_t rx_request;

void uart_init(uint32_t baud)
{
    uint16_t ubrr = (uint16_t)((F_CPU + 4UL * baud) / (8UL * baud) - 1UL);
    UCSR0A = _BV(U2X0);     /* before UBRR: emulators (simavr) take the rate at UBRR write */
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);           /* 8 data bits, no parity, 1 stop */
    UCSR0B = _BV(TXEN0) | _BV(RXEN0) | _BV(RXCIE0);
}

uint8_t uart_tx_free(void)
{
    return (uint8_t)(TX_SIZE - 1u - (uint8_t)(tx_head - tx_tail));
}

void uart_write(const uint8_t *data, uint8_t n)
{
    uint8_t i;
    uint8_t head = tx_head;
    for (i = 0; i < n; ++i)
        tx_buf[(uint8_t)(head + i)] = data[i];
    tx_head = (uint8_t)(head + n);
    UCSR0B |= _BV(UDRIE0);
}

uint8_t uart_request_pending(void)
{
    return rx_request;
}

uint8_t uart_take_request(void)
{
    uint8_t r = rx_request;
    rx_request = 0;
    return r;
}

ISR(USART_UDRE_vect)
{
    uint8_t tail = tx_tail;
    if (tail == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tail];
    tx_tail = (uint8_t)(tail + 1u);
}

ISR(USART_RX_vect)
{
    uint8_t c = UDR0;
    if (c == '?' || c == 'I')
        rx_request = 1;
}
