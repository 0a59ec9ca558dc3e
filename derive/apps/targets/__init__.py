"""Generated C on other targets: cross-compilation for ARM (Cortex-M4F sizes per function,
arm-linux-gnueabihf runs under qemu-arm against the NumPy reference) and the library
layout a firmware project drops in (sources, CMakeLists.txt, Makefile, a test program)."""
