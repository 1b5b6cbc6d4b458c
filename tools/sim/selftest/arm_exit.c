/* bkqemu self-test program: argument-free behaviours chosen at build time.
   -DEXIT_CODE=n returns n; -DHANG never returns; -DFAULT jumps to no code. */
int main(void) {
#if defined(HANG)
  for (;;) {
  }
#elif defined(FAULT)
  void (*f)(void) = (void (*)(void))0x30000001u;  /* no memory there */
  f();
#endif
  return EXIT_CODE;
}
