/* bksim self-test program: echoes UART0 input upper-cased, toggles PF0 (RAMPS
 * X_STEP) once per byte received, and stops on EOT (0x04). Brackets the echo of
 * each line with benchmark markers so the harness's cycle reports are exercised.
 *
 * Built with -DECHO_NEVER_STOPS it behaves like Marlin at the end of a print:
 * after EOT it toggles PF1 200 times, 5 ms apart (1 s of "steps" with no UART
 * traffic), then idles for ever with interrupts on, so only --idle-timeout or
 * a signal ends the run. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <util/delay.h>

static void put(char c) {
  loop_until_bit_is_set(UCSR0A, UDRE0);
  UDR0 = (uint8_t)c;
}

int main(void) {
  UCSR0A = _BV(U2X0);
  UBRR0 = 16; /* 115200 baud at 16 MHz */
  UCSR0B = _BV(TXEN0) | _BV(RXEN0);
  UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
  DDRF |= _BV(PF0) | _BV(PF1);
  for (;;) {
    loop_until_bit_is_set(UCSR0A, RXC0);
    char c = (char)UDR0;
    PORTF ^= _BV(PF0);
    if (c == 4) break;
    if (c >= 'a' && c <= 'z') c = (char)(c - 'a' + 'A');
    put(c);
  }
  loop_until_bit_is_set(UCSR0A, UDRE0);
#ifdef ECHO_NEVER_STOPS
  for (int i = 0; i < 200; i++) {
    _delay_ms(5);
    PORTF ^= _BV(PF1);
  }
  sei();
  for (;;) {
  }
#endif
  cli();
  sleep_enable();
  sleep_cpu();
  for (;;) {
  }
}
