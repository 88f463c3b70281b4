# bass: top-level entry points. `make demo` and `make test` work on a fresh Debian machine.
SHELL := /bin/bash
CARGO ?= cargo
export CARGO_TERM_COLOR ?= never
RELEASE_DIR := target/release
CFLAGS_STRICT := -std=c11 -Wall -Wextra -Wpedantic -Werror

.PHONY: all deps deps-build build build-all build-ship demo test test-rust test-loom test-c test-broker test-replay test-clients test-docs test-faults test-bridge \
        header fmt lint bench install clean install-files deb test-package test-systemd

all: build

# System packages (apt) and Python modules: what the build needs (deps-build), and what
# the tests need on top of it (deps: Octave for the MEX wrapper). `make demo` and `make test`
# run them; `make build` does not (it only compiles).
deps-build:
	scripts/install-deps.sh

deps:
	scripts/install-deps.sh --with-octave

# The default members: the port, the C library, bassd, bass (not bridge/, whose Zenoh build is
# long, nor the bench): see build-all.
build:
	$(CARGO) build --release

# Every crate and every test target of the workspace, in the one cargo invocation every suite,
# script and the bench use (one feature unification: Zenoh and the rest are compiled once in a
# `make test` run; scripts call `make build-all`, never cargo themselves).
build-all:
	$(CARGO) build --release --workspace --all-targets

demo: deps-build build
	scripts/demo.sh

# Everything CI runs.
test: deps lint test-rust test-loom test-c test-broker test-replay test-clients test-docs test-faults test-bridge test-package test-systemd
	@echo "make test: all suites passed"

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --release --workspace --all-targets -- -D warnings

# --workspace includes bridge/ (bass-bridge), which plain `cargo build` (default-members) skips.
test-rust: build-all
	$(CARGO) test --release --workspace

# The loom model of the window protocol (its own cfg, its own target directory).
test-loom:
	RUSTFLAGS="--cfg loom" CARGO_TARGET_DIR=target/loom $(CARGO) test --release -p bassport --test loom_ring

test-c: build
	tests/c/run.sh

test-broker: build
	tests/broker/run.sh

# record -> replay -> compare through the C ABI (tests/replay/run.sh; docs/broker.md).
test-replay: build
	tests/replay/run.sh

test-clients: build
	tests/clients/run.sh

# The README's commands, the tutorial's Octave, Python and shell snippets and docs/clients.md's
# Python run as written against real brokers on sim: devices (tests/docs/run.sh).
test-docs: build
	tests/docs/run.sh

# bass across two network namespaces over Zenoh (root; docs/network.md).
test-bridge: build
	tests/bridge/run.sh

test-faults: build
	tests/faults/run.sh

# Regenerate include/bass.h from the Rust sources.
header:
	BASS_BLESS=1 $(CARGO) test -p bassclient --test header_in_sync

fmt:
	$(CARGO) fmt --all

bench: deps-build
	scripts/bench.sh

# Install the broker, the CLI, the client library (.so, .a), its headers, a pkg-config file and a
# CMake package: make install PREFIX=/opt/bass [DESTDIR=...] (default PREFIX /usr/local).
PREFIX ?= /usr/local
INSTALL_ROOT = $(DESTDIR)$(PREFIX)
BUILT_DIR = $(or $(CARGO_TARGET_DIR),target)/release
VERSION := $(shell sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -1)
# What the package ships (bassd, bass, bass-bridge, libbassclient.so and .a), no test target.
build-ship:
	$(CARGO) build --release -p bass-broker -p bass-cli -p bass-bridge -p bassclient

install: build-ship
	@$(MAKE) --no-print-directory install-files

# The files only, from binaries built before (make deb, tests/package): no cargo run.
install-files:
	install -d $(INSTALL_ROOT)/bin $(INSTALL_ROOT)/lib/pkgconfig $(INSTALL_ROOT)/lib/cmake/bassclient \
	  $(INSTALL_ROOT)/include $(INSTALL_ROOT)/share/bass/matlab $(INSTALL_ROOT)/share/bass/ros2/bass_msgs/msg
	install -m 0755 $(BUILT_DIR)/bassd $(BUILT_DIR)/bass $(BUILT_DIR)/bass-bridge $(INSTALL_ROOT)/bin/
	install -m 0755 $(BUILT_DIR)/libbassclient.so $(INSTALL_ROOT)/lib/libbassclient.so.$(VERSION)
	ln -sf libbassclient.so.$(VERSION) $(INSTALL_ROOT)/lib/libbassclient.so.0
	ln -sf libbassclient.so.0 $(INSTALL_ROOT)/lib/libbassclient.so
	install -m 0644 $(BUILT_DIR)/libbassclient.a $(INSTALL_ROOT)/lib/
	install -m 0644 include/bass.h include/bass.hpp $(INSTALL_ROOT)/include/
	sed -e 's|@PREFIX@|$(PREFIX)|' -e 's|@VERSION@|$(VERSION)|' pkgconfig/bassclient.pc.in \
	  > $(INSTALL_ROOT)/lib/pkgconfig/bassclient.pc
	install -m 0644 cmake/bassclientConfig.cmake $(INSTALL_ROOT)/lib/cmake/bassclient/
	sed -e 's|@VERSION@|$(VERSION)|' cmake/bassclientConfigVersion.cmake.in \
	  > $(INSTALL_ROOT)/lib/cmake/bassclient/bassclientConfigVersion.cmake
	install -m 0644 matlab/bass_mex.c matlab/bass_mex_tables.h matlab/bass_mex_results.h matlab/bass_mex_fields.h matlab/Bass.m matlab/README.md $(INSTALL_ROOT)/share/bass/matlab/
	install -m 0644 ros2/bass_msgs/package.xml ros2/bass_msgs/CMakeLists.txt $(INSTALL_ROOT)/share/bass/ros2/bass_msgs/
	install -m 0644 ros2/bass_msgs/msg/ChunkInfo.msg $(INSTALL_ROOT)/share/bass/ros2/bass_msgs/msg/
	packaging/systemd/install-units.sh $(INSTALL_ROOT) $(PREFIX)
	@echo "installed bass $(VERSION) into $(INSTALL_ROOT)"

# A Debian package of what `make install PREFIX=/usr` installs, with the systemd units and the
# group bass (docs/broker.md, "Running bass as a service"): target/deb/bass_VERSION-1_ARCH.deb.
deb: build-ship
	packaging/debian/build-deb.sh target/deb

# The package built, linted, installed, used and purged on this machine (root; tests/package).
test-package: build-all
	tests/package/run.sh

# The package under a real systemd booted in a minimal Debian root: boot start, READY, a
# blocking C reader, a callback stream and bass blocks riding through a restart, a crash
# within the restart grace and one past it, both C readers through watchdog restarts of a
# stalled device (root; tests/systemd/run.sh; about 60 s, plus about 2 minutes of debootstrap
# the first time on a machine).
test-systemd: build-all
	tests/systemd/run.sh

clean:
	$(CARGO) clean
