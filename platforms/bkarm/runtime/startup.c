/* bkarm start-up: the vector table and the reset code for a bare-metal program
   in QEMU (see bkarm.ld). Output and exit go through semihosting (librdimon),
   so main()'s return value becomes QEMU's exit status; a fault prints a line
   and exits with 70, so a crash fails the run instead of hanging it. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

extern uint32_t __bss_start__, __bss_end__, __stack_top;
extern void (*__preinit_array_start[])(void), (*__preinit_array_end[])(void);
extern void (*__init_array_start[])(void), (*__init_array_end[])(void);
extern void initialise_monitor_handles(void);
extern int main(void);

/* newlib's exit() runs the fini arrays through these; nothing else to do */
void _init(void) {}
void _fini(void) {}

void bk_reset(void) {
  memset(&__bss_start__, 0, (size_t)((char *)&__bss_end__ - (char *)&__bss_start__));
#if defined(__ARM_FP)
  /* CPACR: full access to CP10/CP11, or the first float instruction faults */
  *(volatile uint32_t *)0xE000ED88u |= 0xFu << 20;
  __asm__ volatile("dsb\n\tisb" ::: "memory");
#endif
  /* CCR.UNALIGN_TRP stays off: newlib's memcpy for ARMv7-M reads unaligned
     words on purpose (legal on M3/M4). Misaligned pointer casts in the core
     are caught by the native build's UBSan (-fsanitize=undefined). */
  initialise_monitor_handles();
  for (void (**f)(void) = __preinit_array_start; f < __preinit_array_end; f++) (*f)();
  for (void (**f)(void) = __init_array_start; f < __init_array_end; f++) (*f)();
  exit(main());
}

/* The fault's stacked frame: r0-r3, r12, lr, pc, xpsr. */
__attribute__((used)) static void bk_fault_report(const uint32_t *frame) {
  const uint32_t cfsr = *(volatile uint32_t *)0xE000ED28u, hfsr = *(volatile uint32_t *)0xE000ED2Cu;
  printf("\nbkarm: fault at pc 0x%08lx (lr 0x%08lx), CFSR 0x%08lx, HFSR 0x%08lx%s\n", (unsigned long)frame[6],
         (unsigned long)frame[5], (unsigned long)cfsr, (unsigned long)hfsr,
         (cfsr & (1u << 24)) ? ": unaligned access" : "");
  fflush(stdout);
  exit(70);
}
__attribute__((naked)) static void bk_fault(void) {
  __asm__ volatile("mrs r0, msp\n\tb bk_fault_report");
}

/* Cortex-M: initial stack pointer, then the handlers (reset, NMI, hard fault,
   memory management, bus fault, usage fault; SVC, debug monitor, PendSV and
   SysTick unused: interrupts stay off). */
__attribute__((section(".vectors"), used)) static void (*const bk_vectors[16])(void) = {
    (void (*)(void))&__stack_top, bk_reset, bk_fault, bk_fault, bk_fault, bk_fault, bk_fault,
    0, 0, 0, 0, bk_fault, bk_fault, 0, bk_fault, bk_fault,
};
