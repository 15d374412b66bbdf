// A fake MPU register file behind a host stand-in for the Arduino Wire library.
#pragma once
#include "Arduino.h"

struct HostWire {
  uint8_t regs[128] = {0};
  uint8_t ptr = 0;
  int pending = -1;   // register address just written, awaiting a value
  int avail = 0;
  bool fail_next_read = false;
  void begin() {}
  void setClock(long) {}
  void beginTransmission(int) { pending = -1; }
  size_t write(uint8_t b) {
    if (pending < 0) { ptr = b; pending = b; } else { regs[pending] = b; pending = -1; }
    return 1;
  }
  int endTransmission(bool = true) { return 0; }
  uint8_t requestFrom(uint8_t, uint8_t n) {
    if (fail_next_read) { fail_next_read = false; avail = 0; return 0; }
    avail = n;
    return n;
  }
  int available() { return avail; }
  int read() { --avail; return regs[ptr++]; }
};
extern HostWire Wire;
