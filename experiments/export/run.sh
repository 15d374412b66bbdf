#!/bin/sh
# torchtea export on real static MPU-6050 recordings (issue 31): every format, the model each axis's check --auto ends
# with. Outputs in real/<name>/ (regenerated, not in git); then the table beside an Allan line fit: allan_lines.py.
set -e
cd "$(dirname "$0")"
mkdir -p real
for f in unmoved_x_forward unmoved_z_front_x_up; do              # EUPL, read from ../shared, not vendored
    torchtea export ../../../shared/data/mpu6050_sensor_fusion_temperature/$f.csv \
        --units g,g,g,deg/s,deg/s,deg/s --rate 100 --temperature temp --format all --out real/$f > real/$f.log 2>&1
done
python allan_lines.py real/unmoved_x_forward real/unmoved_z_front_x_up
