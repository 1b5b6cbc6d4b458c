/* bksim self-test program: echoes UART0 input upper-cased, toggles PF0 (RAMPS
 * X_STEP) once per byte received, and stops on EOT (0x04). Brackets the echo of
 * each line with benchmark markers so the harness's cycle reports are exercised. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

static void put(char c) {
  loop_until_bit_is_set(UCSR0A, UDRE0);
  UDR0 = (uint8_t)c;
}

int main(void) {
  UCSR0A = _BV(U2X0);
  UBRR0 = 16; /* 115200 baud at 16 MHz */
  UCSR0B = _BV(TXEN0) | _BV(RXEN0);
  UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
  DDRF |= _BV(PF0);
  for (;;) {
    loop_until_bit_is_set(UCSR0A, RXC0);
    char c = (char)UDR0;
    PORTF ^= _BV(PF0);
    if (c == 4) break;
    if (c >= 'a' && c <= 'z') c = (char)(c - 'a' + 'A');
    put(c);
  }
  loop_until_bit_is_set(UCSR0A, UDRE0);
  cli();
  sleep_enable();
  sleep_cpu();
  for (;;) {
  }
}
