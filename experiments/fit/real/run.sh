#!/bin/sh
# Real-data results of issue 11 on the bundled MPU-6050 recording (100 Hz): its first 30 s and its whole 449 s.
# Writes fit_30s.json, fit_449s.json (fractional+white, exact MLE, 99-replicate fractional test) and the
# identify run directories identify_30s/, identify_449s/ (TEA with the fitted noise levels).
set -e
cd "$(dirname "$0")"
torchtea fit --samples 3000 --bootstrap 99 --out fit_30s.json > fit_30s.txt
torchtea fit --samples all --bootstrap 99 --out fit_449s.json > fit_449s.txt
torchtea identify --out identify_30s --no-plots --json > identify_30s.json
torchtea identify --samples all --memory soe --out identify_449s --no-plots --json > identify_449s.json
