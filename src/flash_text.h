// Constant text and tables in flash on AVR (RAM is 8 KiB there), plain memory
// elsewhere. One set of macros for the whole core.
#ifndef BK_FLASH_TEXT_H
#define BK_FLASH_TEXT_H

#include <string.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define BK_F(s) PSTR(s)                                // a string literal kept in flash
#define BK_FLASH PROGMEM                               // a table kept in flash
#define BK_RD8(p) pgm_read_byte(p)                     // read one byte of it
#define BK_RD32(p) pgm_read_dword(p)
#define BK_RDPTR(p) ((const char *)pgm_read_word(p))  // a flash pointer stored in flash
#define BK_RDBLOCK(dst, src, n) memcpy_P((dst), (src), (n))  // n bytes of a flash table
#define BK_STRNCMP(ram, flash, n) strncmp_P((ram), (flash), (n))
#else
#define BK_F(s) (s)
#define BK_FLASH
#define BK_RD8(p) (*(p))
#define BK_RD32(p) (*(p))
#define BK_RDPTR(p) (*(p))
#define BK_RDBLOCK(dst, src, n) memcpy((dst), (src), (n))
#define BK_STRNCMP(ram, flash, n) strncmp((ram), (flash), (n))
#endif

#endif  // BK_FLASH_TEXT_H
