/* bkqemu self-test program: SysTick under -icount shift=0 counts one tick per
   40 instructions (see test/bktest.cpp). Runs a loop of a known length (two
   instructions per turn) and prints the count SysTick saw, in instructions. */
#include <stdint.h>
#include <stdio.h>

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)

int main(void) {
  SYST_RVR = 0xFFFFFFu;
  SYST_CVR = 0;
  SYST_CSR = 5u;
  for (uint32_t turns = 100000; turns <= 400000; turns *= 2) {
    uint32_t t0 = SYST_CVR;
    __asm__ volatile(
        "   mov r0, %0\n"
        "1: subs r0, #1\n"
        "   bne 1b\n" ::"r"(turns)
        : "r0", "cc");
    uint32_t t1 = SYST_CVR;
    printf("loop %lu turns: %lu instructions\n", (unsigned long)turns, (unsigned long)(((t0 - t1) & 0xFFFFFFu) * 40u));
  }
  return 0;
}
