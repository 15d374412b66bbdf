#!/bin/sh
# issue 32: the TEA on the models `check --auto` ended with on the real MPU-6050 recordings (experiments/check/real/),
# channel by channel at the check's fitted values (`identify --from-check`), beside the TEA on the paper's
# fractional+white fitted to the same channels (`identify`, plain), and the checked models again with KFo and KFw set
# for a constant order and pole (constant.toml: R = "innovation", Q0 = 1e-5). Outputs in real/ (regenerated, not in
# git); then
# python experiments/tea_models/real_table.py   # prints the table of real.md (paste it under the page's title and reading)
set -e
cd "$(dirname "$0")"
mkdir -p real
CHECKS=../check/real
torchtea identify --from-check $CHECKS/bundled/check.json --out real/bundled --no-plots --json > real/bundled.json
torchtea identify --from-check $CHECKS/bundled/check.json --config constant.toml --out real/bundled_constant \
    --no-plots --json > real/bundled_constant.json
torchtea identify --columns ax,ay,az,gx,gy,gz --out real/bundled_plain --no-plots --json > real/bundled_plain.json
for f in unmoved_x_forward unmoved_z_front_x_up; do              # EUPL, read from ../shared, not vendored
    REC=../../../shared/data/mpu6050_sensor_fusion_temperature/$f.csv
    torchtea identify $REC --units g,g,g,deg/s,deg/s,deg/s --rate 100 --from-check $CHECKS/$f/check.json \
        --out real/$f --no-plots --json > real/$f.json
    torchtea identify $REC --units g,g,g,deg/s,deg/s,deg/s --rate 100 --from-check $CHECKS/$f/check.json \
        --config constant.toml --out real/${f}_constant --no-plots --json > real/${f}_constant.json
    torchtea identify $REC --units g,g,g,deg/s,deg/s,deg/s --rate 100 --columns acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z \
        --out real/${f}_plain --no-plots --json > real/${f}_plain.json
done
