#!/bin/sh
# issue 32: the TEA on the models `check --auto` ended with on the real MPU-6050 recordings (experiments/check/real/),
# channel by channel at the check's fitted values: `identify --from-check`. Outputs in real/ (regenerated, not in git);
# the table: python experiments/tea_models/real_table.py > experiments/tea_models/real.md
set -e
cd "$(dirname "$0")"
mkdir -p real
CHECKS=../check/real
torchtea identify --from-check $CHECKS/bundled/check.json --out real/bundled --no-plots --json > real/bundled.json
for f in unmoved_x_forward unmoved_z_front_x_up; do              # EUPL, read from ../shared, not vendored
    torchtea identify ../../../shared/data/mpu6050_sensor_fusion_temperature/$f.csv \
        --units g,g,g,deg/s,deg/s,deg/s --rate 100 --from-check $CHECKS/$f/check.json --out real/$f --no-plots \
        --json > real/$f.json
done
