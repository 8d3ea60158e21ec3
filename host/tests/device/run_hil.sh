#!/bin/sh
# Runs a hardware-in-the-loop test binary under umockdev-wrapper (LD_PRELOAD of libumockdev-preload).
# Under AddressSanitizer the preload library comes before the ASan runtime in the library list, which ASan
# refuses unless told that this is intended.
ASAN_OPTIONS="verify_asan_link_order=0${ASAN_OPTIONS:+:$ASAN_OPTIONS}"
export ASAN_OPTIONS
exec umockdev-wrapper "$@"
