# Warnings and sanitizers shared by every target of the project.
add_library(gs_build_flags INTERFACE)
target_compile_options(gs_build_flags INTERFACE
  -Wall -Wextra -Wshadow -Wpointer-arith -Wformat=2 -Wvla
  $<$<COMPILE_LANGUAGE:C>:-Wstrict-prototypes -Wmissing-prototypes>
  -fno-strict-aliasing)
if(GS_WERROR)
  target_compile_options(gs_build_flags INTERFACE -Werror)
endif()
if(GS_SANITIZE)
  target_compile_options(gs_build_flags INTERFACE
    -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer -g)
  target_link_options(gs_build_flags INTERFACE -fsanitize=address,undefined)
endif()
if(GS_FUZZ)
  # libFuzzer builds (clang): coverage instrumentation for every target,
  # sanitizers on; fuzz executables add -fsanitize=fuzzer at link time.
  target_compile_options(gs_build_flags INTERFACE
    -fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all
    -fno-omit-frame-pointer -g -O1)
  target_link_options(gs_build_flags INTERFACE -fsanitize=address,undefined)
endif()
# Debian's hardening build flags (what dpkg-buildflags gives with
# hardening=+all) in optimized builds, with debug information, which the
# package moves to gazesplat-dbgsym when it strips the binaries.
option(GS_HARDENING "Debian's hardening flags and -g in Release builds" ON)
if(GS_HARDENING AND NOT GS_SANITIZE AND NOT GS_FUZZ)
  target_compile_options(gs_build_flags INTERFACE
    $<$<CONFIG:Release,RelWithDebInfo>:-g -fstack-protector-strong -fstack-clash-protection -fcf-protection>)
  target_compile_definitions(gs_build_flags INTERFACE $<$<CONFIG:Release,RelWithDebInfo>:_FORTIFY_SOURCE=2>)
  target_link_options(gs_build_flags INTERFACE $<$<CONFIG:Release,RelWithDebInfo>:LINKER:-z,relro LINKER:-z,now>)
endif()
