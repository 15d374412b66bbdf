#!/bin/sh
# check --auto from fractional+white on real static MPU-6050 recordings (issues 12, 29, 30), outputs beside this script.
set -e
cd "$(dirname "$0")"
torchtea check --auto --out bundled > run.log 2>&1                      # the bundled 449 s at 100 Hz, six channels, no temperature
for f in unmoved_x_forward unmoved_z_front_x_up; do              # EUPL, read from ../shared, not vendored
    torchtea check ../../../../shared/data/mpu6050_sensor_fusion_temperature/$f.csv \
        --units g,g,g,deg/s,deg/s,deg/s --rate 100 --temperature temp --auto --out $f > run_$f.log 2>&1
done
