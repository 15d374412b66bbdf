// Minimal host stand-ins for the Arduino core, enough to run torchtea_imu.ino on a PC in the tests.
#pragma once
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <string>

#define F(s) (s)
#define HEX 16
#define INPUT 0
#define RISING 3
typedef uint8_t byte;

extern uint32_t host_micros;
inline uint32_t micros() { return host_micros; }
inline void delay(unsigned long) {}
inline void noInterrupts() {}
inline void interrupts() {}
inline void pinMode(int, int) {}
inline int digitalPinToInterrupt(int p) { return p; }
extern void (*host_isr)();
inline void attachInterrupt(int, void (*f)(), int) { host_isr = f; }

struct HostSerial {
  std::string out, in;
  void begin(long) {}
  int available() { return (int)in.size(); }
  int read() { int c = (unsigned char)in[0]; in.erase(0, 1); return c; }
  size_t write(const uint8_t *b, size_t n) { out.append((const char *)b, n); return n; }
  void print(const char *s) { out += s; }
  void print(long v, int base = 10) {
    char b[24];
    snprintf(b, sizeof b, base == 16 ? "%lX" : "%ld", v);
    out += b;
  }
  void println(const char *s) { print(s); out += "\r\n"; }
  void println(long v, int base = 10) { print(v, base); out += "\r\n"; }
};
extern HostSerial Serial;
