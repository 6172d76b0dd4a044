#!/usr/bin/env bash
# Make sure a libLLVM >= 16 is installed for Dr.Jit's LLVM backend.
# Installs Debian's libllvm19 when none is found and we may use apt-get.
set -u
for f in /usr/lib/*-linux-gnu/libLLVM*.so* /usr/lib/llvm-*/lib/libLLVM*.so*; do
  [ -e "$f" ] || continue
  v=$(basename "$f" | sed -nE 's/^libLLVM[-.]?(so\.)?([0-9]+).*/\2/p')
  [ -z "$v" ] && v=$(echo "$f" | sed -nE 's/.*llvm-([0-9]+).*/\1/p')
  if [ -n "$v" ] && [ "$v" -ge 16 ]; then exit 0; fi
done
if command -v apt-get >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo -n"
  echo "corona: installing libllvm19 for Dr.Jit's LLVM backend" >&2
  ($SUDO apt-get update -qq && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19) >/dev/null 2>&1 \
    || echo "corona: could not install libllvm19; the scalar_spectral variant will be used (slow)" >&2
else
  echo "corona: no libLLVM >= 16 found and no apt-get; install LLVM >= 16 for the fast variant" >&2
fi
exit 0
