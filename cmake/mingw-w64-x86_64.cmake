# SPDX-License-Identifier: GPL-3.0-or-later
# Cross-compiling for Windows x64 with Debian's mingw-w64 (g++-mingw-w64-x86-64).
# The -posix compilers: their C++ runtime has threads (winpthreads), which
# OpenSubdiv's core and the library's own threads use.  Tests run under
# Wine (wine64), through ctest.
set(CMAKE_SYSTEM_NAME Windows)
set(CMAKE_SYSTEM_PROCESSOR x86_64)
set(CMAKE_C_COMPILER x86_64-w64-mingw32-gcc-posix)
set(CMAKE_CXX_COMPILER x86_64-w64-mingw32-g++-posix)
set(CMAKE_RC_COMPILER x86_64-w64-mingw32-windres)
set(CMAKE_FIND_ROOT_PATH /usr/x86_64-w64-mingw32)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
find_program(SPIA_WINE NAMES wine64 wine PATHS /usr/lib/wine)
if(SPIA_WINE)
  set(CMAKE_CROSSCOMPILING_EMULATOR ${SPIA_WINE})
endif()
