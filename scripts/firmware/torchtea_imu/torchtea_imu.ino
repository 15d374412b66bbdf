// torchtea_imu — streams an MPU-9250 (or MPU-6050) over serial in torchtea protocol v1.
//
// Samples on the sensor's data-ready interrupt (default 100 Hz, ±8 g, ±250 °/s), one line per
// sample: counter,t_us,ax,ay,az,gx,gy,gz,temp*HH (see docs/protocol.md). The counter counts
// data-ready interrupts, so a sample the sketch could not read in time shows up on the host as a
// gap (a NaN row), never as a shifted sample. Sends its header at start and whenever it receives 'H'.
// Wiring and settings: README.md next to this file.
#include <Wire.h>

#include "tt_protocol.h"

// ---- settings (or pass -D flags with arduino-cli) -------------------------------------------
// #define TT_MPU6050            // uncomment for an MPU-6050 (default: MPU-9250 / MPU-6500)
#ifndef TT_RATE_HZ
#define TT_RATE_HZ 100           // output data rate; 1000 / TT_RATE_HZ must be a whole number
#endif
#ifndef TT_DLPF_CFG
#define TT_DLPF_CFG 3            // digital low-pass: 1..6 (see README); 3 = 44 Hz accel bandwidth
#endif
#ifndef TT_ACCEL_FS
#define TT_ACCEL_FS 2            // 0: ±2 g, 1: ±4 g, 2: ±8 g (paper), 3: ±16 g
#endif
#ifndef TT_GYRO_FS
#define TT_GYRO_FS 0             // 0: ±250, 1: ±500, 2: ±1000, 3: ±2000 °/s
#endif
#ifndef TT_INT_PIN
#define TT_INT_PIN 2             // the sensor's INT pin (must support attachInterrupt)
#endif
#ifndef TT_BAUD
#define TT_BAUD 115200
#endif
#ifndef TT_I2C_ADDR
#define TT_I2C_ADDR 0x68         // AD0 low; 0x69 with AD0 high
#endif

// ---- registers (MPU-6000/6050 and MPU-9250 register maps) -----------------------------------
#define REG_SMPLRT_DIV 0x19
#define REG_CONFIG 0x1A
#define REG_GYRO_CONFIG 0x1B
#define REG_ACCEL_CONFIG 0x1C
#define REG_ACCEL_CONFIG2 0x1D   // MPU-9250 only: accelerometer low-pass
#define REG_INT_PIN_CFG 0x37
#define REG_INT_ENABLE 0x38
#define REG_ACCEL_XOUT_H 0x3B
#define REG_PWR_MGMT_1 0x6B
#define REG_WHO_AM_I 0x75

#if (TT_DLPF_CFG < 1) || (TT_DLPF_CFG > 6)
#error "TT_DLPF_CFG must be 1..6 (0 and 7 change the internal rate to 8 kHz)"
#endif
#if (1000 % TT_RATE_HZ) != 0 || TT_RATE_HZ > 1000 || TT_RATE_HZ < 4
#error "TT_RATE_HZ must divide 1000 and lie in 4..1000"
#endif

#ifdef TT_MPU6050
static const char SENSOR[] = "MPU-6050";
static const char TEMP_LSB[] = "340";      // datasheet: T = raw / 340 + 36.53 °C
static const char TEMP_OFFSET[] = "36.53";
static const char *const DLPF_HZ[] = {"260", "184", "94", "44", "21", "10", "5"};  // accel bandwidth
#else
static const char SENSOR[] = "MPU-9250";
static const char TEMP_LSB[] = "333.87";   // datasheet: T = raw / 333.87 + 21 °C
static const char TEMP_OFFSET[] = "21";
static const char *const DLPF_HZ[] = {"218.1", "218.1", "99", "44.8", "21.2", "10.2", "5.05"};
#endif
static const char *const ACCEL_LSB[] = {"16384", "8192", "4096", "2048"};
static const char *const GYRO_LSB[] = {"131", "65.5", "32.8", "16.4"};

static volatile uint32_t isr_count = 0;   // data-ready interrupts since start
static volatile uint32_t isr_micros = 0;  // micros() at the latest one
static uint32_t read_count = 0;
static bool sensor_ok = false;

static void on_data_ready() {
  isr_micros = micros();
  ++isr_count;
}

static void write_reg(uint8_t reg, uint8_t value) {
  Wire.beginTransmission(TT_I2C_ADDR);
  Wire.write(reg);
  Wire.write(value);
  Wire.endTransmission();
}

static uint8_t read_reg(uint8_t reg) {
  Wire.beginTransmission(TT_I2C_ADDR);
  Wire.write(reg);
  Wire.endTransmission(false);
  Wire.requestFrom((uint8_t)TT_I2C_ADDR, (uint8_t)1);
  return Wire.available() ? Wire.read() : 0xFF;
}

static void print_header() {
  Serial.println(F("# torchtea-imu 1"));
  Serial.print(F("# sensor=")); Serial.println(SENSOR);
  Serial.print(F("# rate_hz=")); Serial.println(TT_RATE_HZ);
  Serial.print(F("# accel_lsb_per_g=")); Serial.println(ACCEL_LSB[TT_ACCEL_FS]);
  Serial.print(F("# gyro_lsb_per_dps=")); Serial.println(GYRO_LSB[TT_GYRO_FS]);
  Serial.print(F("# temp_lsb_per_c=")); Serial.println(TEMP_LSB);
  Serial.print(F("# temp_offset_c=")); Serial.println(TEMP_OFFSET);
  Serial.print(F("# dlpf_hz=")); Serial.println(DLPF_HZ[TT_DLPF_CFG]);
  Serial.print(F("# dlpf_cfg=")); Serial.println(TT_DLPF_CFG);
  Serial.print(F("# who_am_i=0x")); Serial.println(read_reg(REG_WHO_AM_I), HEX);
  Serial.println(F("# firmware=torchtea_imu 1"));
  Serial.println(F("# columns=counter,t_us,ax,ay,az,gx,gy,gz,temp"));
}

void setup() {
  Serial.begin(TT_BAUD);
  Wire.begin();
  Wire.setClock(400000);  // 14 bytes in ~0.4 ms
  write_reg(REG_PWR_MGMT_1, 0x80);  // reset
  delay(100);
  write_reg(REG_PWR_MGMT_1, 0x01);  // wake, PLL with the X gyro as clock
  delay(10);
  uint8_t who = read_reg(REG_WHO_AM_I);
  sensor_ok = (who == 0x68 || who == 0x70 || who == 0x71 || who == 0x73);
  write_reg(REG_CONFIG, TT_DLPF_CFG);                       // gyro DLPF → 1 kHz internal rate
  write_reg(REG_SMPLRT_DIV, (uint8_t)(1000 / TT_RATE_HZ - 1));
  write_reg(REG_GYRO_CONFIG, (uint8_t)(TT_GYRO_FS << 3));
  write_reg(REG_ACCEL_CONFIG, (uint8_t)(TT_ACCEL_FS << 3));
#ifndef TT_MPU6050
  write_reg(REG_ACCEL_CONFIG2, TT_DLPF_CFG);                // accel DLPF on (ACCEL_FCHOICE_B = 0)
#endif
  write_reg(REG_INT_PIN_CFG, 0x10);  // active high, push-pull, 50 µs pulse, cleared by any read
  write_reg(REG_INT_ENABLE, 0x01);   // DATA_RDY_EN
  print_header();
  if (!sensor_ok) {
    Serial.print(F("# error=no MPU at the I2C address (WHO_AM_I 0x"));
    Serial.print(who, HEX);
    Serial.println(F("); check the wiring"));
    return;
  }
  pinMode(TT_INT_PIN, INPUT);
  attachInterrupt(digitalPinToInterrupt(TT_INT_PIN), on_data_ready, RISING);
}

void loop() {
  while (Serial.available()) {
    if (Serial.read() == 'H') print_header();
  }
  if (!sensor_ok) return;
  noInterrupts();
  uint32_t count = isr_count;
  uint32_t t_us = isr_micros;
  interrupts();
  if (count == read_count) return;  // no new sample
  // read the newest sample; interrupts we were too slow for become counter gaps on the host
  Wire.beginTransmission(TT_I2C_ADDR);
  Wire.write(REG_ACCEL_XOUT_H);
  Wire.endTransmission(false);
  if (Wire.requestFrom((uint8_t)TT_I2C_ADDR, (uint8_t)14) != 14) return;  // the host sees a gap
  uint8_t raw[14];
  for (int i = 0; i < 14; ++i) raw[i] = Wire.read();
  // register order: accel x,y,z, temperature, gyro x,y,z (big-endian int16)
  int16_t v[7];
  static const uint8_t order[7] = {0, 1, 2, 4, 5, 6, 3};  // → ax, ay, az, gx, gy, gz, temp
  for (int i = 0; i < 7; ++i) {
    uint8_t j = order[i];
    v[i] = (int16_t)((uint16_t)raw[2 * j] << 8 | raw[2 * j + 1]);
  }
  char line[TT_MAX_LINE];
  size_t n = tt_format_line(line, count - 1, t_us, v);
  Serial.write((const uint8_t *)line, n);
  read_count = count;
}
