#!/usr/bin/env bash
# Install the distribution packages the firmware builds and tests need, when they are missing:
# the AVR toolchain and simavr (ATmega328P board), the Arm toolchain, newlib and QEMU (the
# STM32F405 board, run in qemu-system-arm's netduinoplus2 machine), and Chromium with its driver
# (the web view's browser test).
# Runs apt-get only as root; otherwise prints the command to run and fails (exit 2).
set -euo pipefail

packages=(gcc-avr avr-libc simavr libsimavr-dev libsimavrparts1
          gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm
          chromium chromium-driver)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0

if [ "$(id -u)" -ne 0 ]; then
    echo "missing system packages: ${missing[*]}" >&2
    echo "fix: sudo apt-get update && sudo apt-get install -y ${missing[*]}" >&2
    exit 2
fi
echo "installing system packages: ${missing[*]}"
apt-get update -qq
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
