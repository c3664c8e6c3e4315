# Install layout (FHS, GNUInstallDirs) and the Debian package (CPack DEB).
# The default prefix is /usr (set in the top CMakeLists.txt): gazesplatd is a
# system service whose unit names its binary and configuration by absolute
# path. With prefix /usr:
#   /usr/bin/gazesplat, /usr/sbin/gazesplatd
#   /etc/gazesplat/gazesplatd.conf                   (a conffile in the .deb)
#   /usr/lib/systemd/system/gazesplatd.{service,socket}
#   /usr/lib/sysusers.d/gazesplat.conf
#   /usr/share/gazesplat/models/gazegaussian-cpu.safetensors
#   /usr/lib/python3/dist-packages/gazesplat/        (the Python package: clients, Dataset,
#                                                     grid tool, generated messages)
#   /usr/bin/gazesplat-grid                          (its grid tool)
#   /usr/share/doc/gazesplat/                        (README, daemon, protocol, docs)
# The binaries and units are installed by the targets' own directories
# (install(TARGETS) there), the Python package by clients/python; everything
# else here.

set(GS_SYSTEMD_UNITDIR "lib/systemd/system" CACHE STRING
  "systemd system unit directory (relative: under the prefix)")
set(GS_SYSUSERSDIR "lib/sysusers.d" CACHE STRING
  "sysusers.d directory (relative: under the prefix)")

set(GS_CONFDIR ${CMAKE_INSTALL_FULL_SYSCONFDIR}/gazesplat)
set(GS_DATADIR ${CMAKE_INSTALL_FULL_DATADIR}/gazesplat)
set(GS_DEFAULT_MODEL gazegaussian-cpu.safetensors)

# The source unit and configuration name the /usr layout; rewrite the paths
# for the configured prefix so ExecStart, --config and `model` always point
# at what this install puts down.
function(gs_configure_layout src dst)
  file(READ ${src} text)
  string(REPLACE "/usr/sbin/gazesplatd" "${CMAKE_INSTALL_FULL_SBINDIR}/gazesplatd" text "${text}")
  string(REPLACE "/etc/gazesplat/" "${GS_CONFDIR}/" text "${text}")
  string(REPLACE "/usr/share/gazesplat/" "${GS_DATADIR}/" text "${text}")
  file(GENERATE OUTPUT ${dst} CONTENT "${text}")
  set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${src})
endfunction()

set(gs_stage ${CMAKE_BINARY_DIR}/install-files)
gs_configure_layout(${PROJECT_SOURCE_DIR}/systemd/gazesplatd.service ${gs_stage}/gazesplatd.service)
gs_configure_layout(${PROJECT_SOURCE_DIR}/daemon/gazesplatd.conf ${gs_stage}/gazesplatd.conf)

install(FILES ${gs_stage}/gazesplatd.conf DESTINATION ${GS_CONFDIR})
install(FILES ${gs_stage}/gazesplatd.service ${PROJECT_SOURCE_DIR}/systemd/gazesplatd.socket
  DESTINATION ${GS_SYSTEMD_UNITDIR})
install(FILES ${PROJECT_SOURCE_DIR}/systemd/gazesplat.sysusers
  DESTINATION ${GS_SYSUSERSDIR} RENAME gazesplat.conf)
install(FILES ${PROJECT_SOURCE_DIR}/systemd/gazesplat-v4l2loopback.modprobe.conf
  DESTINATION lib/modprobe.d RENAME gazesplat-v4l2loopback.conf)
install(FILES ${PROJECT_SOURCE_DIR}/systemd/gazesplat-v4l2loopback.modules-load.conf
  DESTINATION ${CMAKE_INSTALL_DOCDIR}/examples)
# The gaze estimators: check-labels and eval-downstream read gaze-resnet by
# default; the others are its white-background and VGG variants.
install(FILES ${PROJECT_SOURCE_DIR}/models/${GS_DEFAULT_MODEL} ${PROJECT_SOURCE_DIR}/models/README.md
  ${PROJECT_SOURCE_DIR}/models/gaze-resnet.safetensors
  ${PROJECT_SOURCE_DIR}/models/gaze-resnet-white.safetensors
  ${PROJECT_SOURCE_DIR}/models/gaze-vgg.safetensors
  ${PROJECT_SOURCE_DIR}/models/gaze-vgg-white.safetensors
  DESTINATION ${CMAKE_INSTALL_DATADIR}/gazesplat/models)
install(FILES ${PROJECT_SOURCE_DIR}/samples/astronaut.jpg ${PROJECT_SOURCE_DIR}/samples/README.md
  DESTINATION ${CMAKE_INSTALL_DATADIR}/gazesplat/samples)
install(FILES ${PROJECT_SOURCE_DIR}/README.md ${PROJECT_SOURCE_DIR}/proto/PROTOCOL.md
  ${PROJECT_SOURCE_DIR}/proto/gazesplat.proto DESTINATION ${CMAKE_INSTALL_DOCDIR})
install(FILES ${PROJECT_SOURCE_DIR}/daemon/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR}
  RENAME gazesplatd.md)
install(DIRECTORY ${PROJECT_SOURCE_DIR}/docs/ DESTINATION ${CMAKE_INSTALL_DOCDIR}/docs
  FILES_MATCHING PATTERN "*.md" PATTERN "*.png")

# A native package's changelog, compressed like the man pages.
add_custom_command(OUTPUT ${CMAKE_BINARY_DIR}/deb/changelog.gz
  COMMAND ${CMAKE_COMMAND} -E make_directory ${CMAKE_BINARY_DIR}/deb
  COMMAND gzip -9n -c ${PROJECT_SOURCE_DIR}/cmake/deb/changelog > ${CMAKE_BINARY_DIR}/deb/changelog.gz
  DEPENDS ${PROJECT_SOURCE_DIR}/cmake/deb/changelog VERBATIM)
add_custom_target(gs_changelog ALL DEPENDS ${CMAKE_BINARY_DIR}/deb/changelog.gz)
install(FILES ${CMAKE_BINARY_DIR}/deb/changelog.gz DESTINATION ${CMAKE_INSTALL_DOCDIR})

# Man pages, compressed as Debian wants them (gzip -9n: no name or time
# stamp, so the same bytes every build).
find_program(GS_GZIP gzip)
set(gs_man_gz)
foreach(page gazesplat.1 gazesplat-grid.1 gazesplatd.8 gazesplatd.conf.5)
  set(src ${PROJECT_SOURCE_DIR}/docs/man/${page})
  set(dst ${CMAKE_BINARY_DIR}/man/${page}.gz)
  add_custom_command(OUTPUT ${dst}
    COMMAND ${CMAKE_COMMAND} -E make_directory ${CMAKE_BINARY_DIR}/man
    COMMAND ${GS_GZIP} -9n -c ${src} > ${dst}
    DEPENDS ${src} VERBATIM)
  list(APPEND gs_man_gz ${dst})
  string(REGEX MATCH "[0-9]$" section ${page})
  install(FILES ${dst} DESTINATION ${CMAKE_INSTALL_MANDIR}/man${section})
endforeach()
add_custom_target(gs_man ALL DEPENDS ${gs_man_gz})

# ---- Debian package ----------------------------------------------------------
set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME gazesplat)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "gaze redirection service (GazeGaussian) with its clients")
set(CPACK_PACKAGE_DESCRIPTION
  "gazesplatd serves GazeGaussian gaze redirection (3D Gaussian splatting and\n\
a neural renderer, on the CPU) over a Unix socket; gazesplat is its\n\
command-line client and tool box. Ships the default model, systemd units,\n\
man pages and the Python package gazesplat.")
set(CPACK_PACKAGE_CONTACT "gazesplat maintainers <gazesplat@localhost>")
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
# The package holds what `cmake --install` puts down for this build's prefix
# (/usr unless configured otherwise), so the unit's paths hold in it too.
set(CPACK_PACKAGING_INSTALL_PREFIX ${CMAKE_INSTALL_PREFIX})
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
# Libraries from the binaries' ELF needs (dpkg-shlibdeps); data files the
# daemon opens by path are listed by hand.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_DEPENDS "libdlib-data, opencv-data, systemd")
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "python3, python3-protobuf")
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "python3-pil, python3-numpy, python3-torch, v4l2loopback-dkms")
configure_file(${PROJECT_SOURCE_DIR}/cmake/deb/conffiles.in ${CMAKE_BINARY_DIR}/deb/conffiles @ONLY)
foreach(script postinst prerm postrm)
  set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/cmake/deb/${script})
  file(COPY ${PROJECT_SOURCE_DIR}/cmake/deb/${script} DESTINATION ${CMAKE_BINARY_DIR}/deb
    FILE_PERMISSIONS OWNER_READ OWNER_WRITE OWNER_EXECUTE GROUP_READ GROUP_EXECUTE WORLD_READ WORLD_EXECUTE)
endforeach()
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
  ${CMAKE_BINARY_DIR}/deb/conffiles ${CMAKE_BINARY_DIR}/deb/postinst
  ${CMAKE_BINARY_DIR}/deb/prerm ${CMAKE_BINARY_DIR}/deb/postrm)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
# Stripped binaries in the package, their debug information (the Release
# build's -g, cmake/GazesplatWarnings.cmake) in gazesplat-dbgsym, a .ddeb
# found by build id. (CPACK_STRIP_FILES would strip before the split and
# leave the dbgsym package empty.)
set(CPACK_DEBIAN_DEBUGINFO_PACKAGE ON)
# The maintainer scripts' deb-systemd-helper and deb-systemd-invoke come
# with init-system-helpers, an essential package: not a declared dependency.
include(CPack)
