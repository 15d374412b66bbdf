// torchtea IMU protocol v1: one data line, formatted without printf (small and exact on AVR).
//
//   counter,t_us,ax,ay,az,gx,gy,gz,temp*HH\r\n
//
// HH = XOR of every byte before '*', two upper-case hex digits. Plain C: the host tests compile
// this file with g++ and parse its output with torchtea's parser (tests/test_firmware.py).
#ifndef TT_PROTOCOL_H
#define TT_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

// Longest line: two 10-digit u32, seven 6-character int16, 8 commas, "*HH\r\n".
#define TT_MAX_LINE (10 + 1 + 10 + 7 * (1 + 6) + 5)

static inline size_t tt_put_u32(char *out, uint32_t v) {
  char tmp[10];
  size_t n = 0;
  do {
    tmp[n++] = (char)('0' + (v % 10u));
    v /= 10u;
  } while (v != 0u);
  for (size_t i = 0; i < n; ++i) out[i] = tmp[n - 1 - i];
  return n;
}

static inline size_t tt_put_i16(char *out, int16_t v) {
  if (v < 0) {
    out[0] = '-';
    // -(int32) avoids overflow at -32768
    return 1 + tt_put_u32(out + 1, (uint32_t)(-(int32_t)v));
  }
  return tt_put_u32(out, (uint32_t)v);
}

// values: ax, ay, az, gx, gy, gz, temp (raw counts). Returns the number of bytes written to
// buf (at least TT_MAX_LINE long); no terminating NUL.
static inline size_t tt_format_line(char *buf, uint32_t counter, uint32_t t_us, const int16_t values[7]) {
  static const char hex[] = "0123456789ABCDEF";
  size_t n = tt_put_u32(buf, counter);
  buf[n++] = ',';
  n += tt_put_u32(buf + n, t_us);
  for (int i = 0; i < 7; ++i) {
    buf[n++] = ',';
    n += tt_put_i16(buf + n, values[i]);
  }
  uint8_t x = 0;
  for (size_t i = 0; i < n; ++i) x ^= (uint8_t)buf[i];
  buf[n++] = '*';
  buf[n++] = hex[x >> 4];
  buf[n++] = hex[x & 0x0F];
  buf[n++] = '\r';
  buf[n++] = '\n';
  return n;
}

#endif  // TT_PROTOCOL_H
