// Runs the sketch on the host: commands on stdin, the serial output on stdout.
//   S ax ay az t gx gy gz   set the sensor's registers (raw int16, register order: temperature 4th)
//   I us                    a data-ready interrupt at micros() = us
//   L                       one loop()
//   F                       the next I2C read fails
//   R c                     the host sends byte c
#include <iostream>
#include "Arduino.h"
#include "Wire.h"

uint32_t host_micros = 0;
void (*host_isr)() = nullptr;
HostSerial Serial;
HostWire Wire;

#include "../../scripts/firmware/torchtea_imu/torchtea_imu.ino"

int main() {
  Wire.regs[0x75] = WHO;  // WHO_AM_I
  setup();
  std::string cmd;
  while (std::cin >> cmd) {
    if (cmd == "S") {
      for (int i = 0; i < 7; ++i) {
        long v; std::cin >> v;
        uint16_t u = (uint16_t)(int16_t)v;
        Wire.regs[0x3B + 2 * i] = u >> 8;
        Wire.regs[0x3B + 2 * i + 1] = u & 0xFF;
      }
    } else if (cmd == "I") {
      std::cin >> host_micros;
      if (host_isr) host_isr();
    } else if (cmd == "L") {
      loop();
    } else if (cmd == "F") {
      Wire.fail_next_read = true;
    } else if (cmd == "R") {
      std::string c; std::cin >> c; Serial.in += c;
    }
  }
  std::cout << Serial.out;
  fprintf(stderr, "regs 19=%d 1A=%d 1B=%d 1C=%d 1D=%d 37=%d 38=%d 6B=%d\n", Wire.regs[0x19], Wire.regs[0x1A],
          Wire.regs[0x1B], Wire.regs[0x1C], Wire.regs[0x1D], Wire.regs[0x37], Wire.regs[0x38], Wire.regs[0x6B]);
  return 0;
}
