#!/bin/sh
# check of fractional+white on real static MPU-6050 recordings (issue 12), outputs beside this script.
set -e
cd "$(dirname "$0")"
torchtea check --out bundled > run.log 2>&1                      # the bundled 449 s at 100 Hz, no temperature
torchtea check ../../../../shared/data/mpu6050_sensor_fusion_temperature/unmoved_x_forward.csv \
    --columns acc_x,acc_y,acc_z --units g --rate 100 --time-column none --temperature temp \
    --out unmoved_x_forward > run_unmoved.log 2>&1               # EUPL, read from ../shared, not vendored
