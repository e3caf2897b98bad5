#!/usr/bin/env bash
# CapsuleRT API by curl: the README's examples (tests/e2e/test_curl.py runs this file).
# Start a server first (`make run` or `capsule-rt serve`); BASE_URL defaults to it.
set -euo pipefail
BASE_URL="${BASE_URL:-http://127.0.0.1:8000}"

# 1. Liveness.
curl -fsS "$BASE_URL/healthz"; echo

# 2. Every tissue's permittivity, conductivity, velocity, attenuation and wavelength at 402 MHz.
curl -fsS "$BASE_URL/v1/tissues?frequency_hz=402e6"; echo

# 3. TOA Cramer-Rao bound: 402 MHz tone, 25 ns, 10 GHz bandwidth, SNR 30 dB (about 0.032 mm).
curl -fsS -X POST "$BASE_URL/v1/bounds/toa" -H 'Content-Type: application/json' \
  -d '{"carrier_hz": 402e6, "duration_s": 25e-9, "bandwidth_hz": 10e9, "snr_db": 30, "relative_permittivity": 27.9}'; echo

# 4. Ray-trace the thesis' three-path case (Fig 5.5/5.6): paths with delays and complex gains.
curl -fsS -X POST "$BASE_URL/v1/channel" -H 'Content-Type: application/json' \
  -d '{"scenario": "thesis-fig-5-6", "rays": 20000}'; echo

# 5. TOA ranging (generalized cross-correlation) on a one-path profile, 50 noisy trials at 30 dB.
curl -fsS -X POST "$BASE_URL/v1/ranging/toa" -H 'Content-Type: application/json' \
  -d '{"profile": {"paths": [{"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0}}]},
       "method": "gcc", "snr_db": 30, "trials": 50, "seed": 1, "true_distance_m": 0.076}'; echo
