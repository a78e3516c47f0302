/*
 * accel_calib_fw: interrupt-driven UART0 transmitter (ring buffer) and request receiver.
 *
 * SPDX-License-Identifier: Apache-2.0
 */
#ifndef ACF_UART_H
#define ACF_UART_H

#include <stdint.h>

void uart_init(uint32_t baud);
/* Bytes free in the transmit ring. */
uint8_t uart_tx_free(void);
/* Queue n bytes; the caller checked uart_tx_free() >= n. */
void uart_write(const uint8_t *data, uint8_t n);
/* Return the "info requested" flag without clearing it. */
uint8_t uart_request_pending(void);
/* Return and clear the "info requested" flag (set by '?' or 'I' received). */
uint8_t uart_take_request(void);

#endif
