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
