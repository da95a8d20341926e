# slimfarm - one plain Makefile, no configure step.
#
#   make            release build into build/rel (bin/ links to it)
#   make check      deps, sanitizer build (-Werror, ASan+UBSan), the release build, every test
#   make check-pg   the store's tests on SQLite and on a PostgreSQL server of their own
#   make demo       deps, build, run the farm on embedded defaults (ONCE=1 exits)
#   make bench      benchmarks against peers; prints figures, never fails on time
#   make fuzz T=NAME SECS=60   long libFuzzer run of one parser
#   make deps       install missing Debian packages (quiet when all present)
#   make format / check-format / check-headers / check-layers / check-size / install / clean
#
# Sources are found by wildcard: a new .c file in a library folder joins the
# library, tests/unit/test_NAME.c becomes a test program, tests/fuzz/fuzz_NAME.c
# a fuzz target.  Folders, in dependency order (tests/check-layers.sh):
# src/base src/mesh src/geom slicer drivers src/farm src/api src/cmd; sim uses base.
# drivers/ and sim/ hold one folder per printer family (marlin, net, bambu).

SHELL := /bin/bash
CC := gcc
CXX := g++
FUZZCC := clang-14
PREFIX ?= /usr/local

# Debian 12 packages the project needs; `make deps` installs what is missing.
DEB_PKGS := build-essential pkg-config libserialport-dev libcurl4-openssl-dev libsqlite3-dev \
	libmicrohttpd-dev libmosquitto-dev libinih-dev libqhull-dev libpolyclipping-dev \
	libjansson-dev libminizip-dev libexpat1-dev libcairo2-dev libembree-dev libtet1.5-dev \
	libsuitesparse-dev libpq-dev postgresql clang-14 clang-format libclang-rt-14-dev python3 procps libssl-dev \
	printrun-common mosquitto chromium nodejs python3-aiosmtpd
# Only for `make bench`: the independent peers and their helpers, and OpenSCAD
# (its CLI generates the validation sets, tests/bench/valsets.sh).
BENCH_PKGS := prusa-slicer cura-engine cura time valgrind hyperfine python3-numpy bc openscad
# Wanted by `make check` but not required: tests that need them skip without
# (tests/integ/slice_mech.sh generates its parts with OpenSCAD).
CHECK_OPT_PKGS := openscad
# shell: the packages of the list $(1) that dpkg has not installed, one a line
MISSING = for p in $(1); do dpkg-query -W -f='$${db:Status-Status}\n' $$p 2>/dev/null | grep -qx installed || echo $$p; done

# Libraries with a pkg-config file; the rest get fixed flags (Debian ships no .pc).
PKGS := libserialport libcurl sqlite3 libpq libmicrohttpd libmosquitto inih qhull_r polyclipping \
	jansson minizip expat cairo libcrypto libssl
PKG_CFLAGS = $(shell pkg-config --cflags $(PKGS) 2>/dev/null)
PKG_LIBS = $(shell pkg-config --libs $(PKGS) 2>/dev/null)
EXT_CFLAGS = $(PKG_CFLAGS) -I/usr/include/suitesparse
EXT_LIBS = $(PKG_LIBS) -lembree3 -ltet -lcholmod -lumfpack -lamd -lcolamd -lsuitesparseconfig \
	-lstdc++ -lpthread -lm

ifeq ($(SAN),1)
BUILD := build/san
OPT := -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer
else
BUILD := build/rel
OPT := -O2 -g
endif

# Truncated messages are by design (fixed error buffers), so no format-truncation.
WARN := -Wall -Wextra -Werror -Wshadow -Wformat=2 -Wno-format-nonliteral -Wno-format-truncation
CFLAGS := -std=c11 -D_GNU_SOURCE $(OPT) $(WARN) -Wstrict-prototypes -Wmissing-prototypes \
	-include src/base/compat.h -MMD -MP
CXXFLAGS := -std=c++14 -D_GNU_SOURCE $(OPT) $(WARN) -MMD -MP
LDFLAGS := $(filter -fsanitize=%,$(OPT))
# Hot geometry kernels written as branch-free structure-of-arrays loops: -O3
# lets gcc vectorise them (-O2's very-cheap cost model refuses loops that
# need an epilogue).  Measured with callgrind in the commit that added this.
HOT_OBJS := src/geom/proxy.o src/geom/polar.o src/geom/arap.o
$(addprefix $(BUILD)/obj/,$(HOT_OBJS)): CFLAGS += -O3
# The nearest-rotation kernel takes square roots in its lane loops; without
# errno semantics gcc can vectorize them (callgrind: 1023 -> 760 instructions
# a matrix, bench_slim).  Nothing there reads errno.  -std=c11 turns off
# fused multiply-adds (ISO contraction rules); the ARAP kernels want them
# (callgrind, AVX2 clone: polar 169M -> 140M instructions per 100
# iterations on 9,290 tets).
$(BUILD)/obj/src/geom/polar.o: CFLAGS += -fno-math-errno -ffp-contract=fast
$(BUILD)/obj/src/geom/arap.o: CFLAGS += -ffp-contract=fast

LIB_DIRS := src/base src/mesh src/geom slicer drivers src/farm src/api
# A library folder's sources, and those of its family folders one level down
# (drivers/marlin, drivers/net, sim/bambu, ...).
LIB_C := $(wildcard $(addsuffix /*.c,$(LIB_DIRS)) $(addsuffix /*/*.c,$(LIB_DIRS)))
LIB_CXX := $(wildcard $(addsuffix /*.cpp,$(LIB_DIRS)) $(addsuffix /*/*.cpp,$(LIB_DIRS)))
SIM_C := $(filter-out sim/slimfarm_sim.c,$(wildcard sim/*.c sim/*/*.c))
# The CLI: bin/slimfarm (src/cmd/slimfarm.c, no libraries) execs
# libexec/slimfarm/slimfarm-MODULE, one program per src/cmd/cmd_MODULE.c (with
# its parts cmd_MODULE_*.c and the shared cmd.c), each linked --as-needed so
# it loads only the libraries its commands use.  The helpers that need a
# library (cmdprofile.c: the INI parser; cmdreport.c: jansson) sit in an
# archive, so a program links one only when it calls it.
CMD_MODULES := $(sort $(foreach f,$(wildcard src/cmd/cmd_*.c),\
	$(firstword $(subst _, ,$(patsubst src/cmd/cmd_%.c,%,$(f))))))
CMD_PROGS := $(CMD_MODULES:%=$(BUILD)/libexec/slimfarm/slimfarm-%)
CMD_HELPERS := $(filter-out src/cmd/cmd.c,$(wildcard src/cmd/cmd[a-z]*.c))
TEST_C := $(wildcard tests/unit/test_*.c)
FUZZ_C := $(wildcard tests/fuzz/fuzz_*.c)
BENCH_C := $(wildcard tests/bench/bench_*.c)
# Programs the integration tests drive (tests/tools/*.c, libc alone): the partition proxy.
TOOL_C := $(wildcard tests/tools/*.c)

obj = $(patsubst %.c,$(BUILD)/obj/%.o,$(patsubst %.cpp,$(BUILD)/obj/%.o,$(1)))
LIB := $(BUILD)/libslimfarm.a
SIMLIB := $(BUILD)/libsfsim.a
PROGS := $(BUILD)/bin/slimfarm $(if $(wildcard src/cmd/slimfarmd.c),$(BUILD)/bin/slimfarmd) \
	$(if $(wildcard sim/slimfarm_sim.c),$(BUILD)/bin/slimfarm-sim)
TESTS := $(patsubst tests/unit/%.c,$(BUILD)/tests/%,$(TEST_C)) \
	$(patsubst tests/fuzz/fuzz_%.c,$(BUILD)/tests/test_fuzz_%,$(FUZZ_C))
BENCHES := $(patsubst tests/bench/%.c,$(BUILD)/bench/%,$(BENCH_C))
TOOLS := $(patsubst tests/tools/%.c,$(BUILD)/tests/tools/%,$(TOOL_C))
FUZZERS := $(patsubst tests/fuzz/%.c,build/fuzz/%,$(FUZZ_C))

.PHONY: all check check-pg check-chaos tests demo bench soak fuzz fuzzers deps install clean format check-format \
	check-headers check-layers check-size browser-deps
.DEFAULT_GOAL := all

all: $(PROGS)
	@mkdir -p bin && for p in $(PROGS); do ln -sf ../$$p bin/; done

tests: $(PROGS) $(TESTS) $(TOOLS)

# V=1 shows whole command lines.
Q := $(if $(V),,@)
$(BUILD)/obj/%.o: %.c
	@mkdir -p $(dir $@)
	@$(if $(V),,echo "  CC    $<")
	$(Q)$(CC) $(CFLAGS) $(EXT_CFLAGS) -c $< -o $@

$(BUILD)/obj/%.o: %.cpp
	@mkdir -p $(dir $@)
	@$(if $(V),,echo "  CXX   $<")
	$(Q)$(CXX) $(CXXFLAGS) $(EXT_CFLAGS) -c $< -o $@

# The dashboard's static files (src/api/web/), embedded as C arrays (web.h).
WEB_FILES := $(filter-out %.sh,$(wildcard src/api/web/*))
build/gen/web_assets.c: $(WEB_FILES) src/api/web/embed.sh
	@mkdir -p $(dir $@)
	$(Q)src/api/web/embed.sh $(WEB_FILES) > $@.tmp && mv $@.tmp $@
$(BUILD)/obj/gen/web_assets.o: build/gen/web_assets.c
	@mkdir -p $(dir $@)
	$(Q)$(CC) $(CFLAGS) -I. -c $< -o $@

$(LIB): $(call obj,$(LIB_C) $(LIB_CXX)) $(BUILD)/obj/gen/web_assets.o
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^

$(SIMLIB): $(call obj,$(SIM_C))
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^ $(if $^,,)

.SECONDEXPANSION:
.SECONDARY: $(call obj,$(wildcard src/cmd/cmd*.c))
$(BUILD)/libcmd.a: $(call obj,$(CMD_HELPERS))
	rm -f $@ && ar rcs $@ $^
$(BUILD)/libexec/slimfarm/slimfarm-%: $(call obj,src/cmd/cmd.c) $(BUILD)/obj/src/cmd/cmd_%.o \
		$$(call obj,$$(wildcard src/cmd/cmd_$$*_*.c)) $(BUILD)/libcmd.a $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $^ -Wl,--as-needed $(EXT_LIBS)

# The front door's command table, from the programs themselves (cmd.c --describe).
$(BUILD)/gen/commands.inc: $(CMD_PROGS)
	@mkdir -p $(dir $@)
	$(Q)for m in $(CMD_MODULES); do $(BUILD)/libexec/slimfarm/slimfarm-$$m --describe $$m || exit 1; \
		done | LC_ALL=C sort > $@.tmp && mv $@.tmp $@
$(BUILD)/obj/src/cmd/slimfarm.o: $(BUILD)/gen/commands.inc
$(BUILD)/obj/src/cmd/slimfarm.o: CFLAGS := $(filter-out -fsanitize=% -fno-sanitize-recover=%,\
	$(CFLAGS)) -I$(BUILD)/gen

# The front door is linked statically (position-independent, so ASLR stays):
# every `slimfarm CMD` pays its start-up before the command program's own,
# and without the dynamic loader it halves (perf stat, `slimfarm help
# orient`: 56 -> 26 page faults, 3.3 -> 1.6 ms task-clock).  It calls only
# libc and no NSS function, so static glibc is safe.  Never sanitized, in
# any build: ASan cannot link statically, and the tests should run the form
# that ships (100 lines of argv handling).
$(BUILD)/bin/slimfarm: $(call obj,src/cmd/slimfarm.c)
	@mkdir -p $(dir $@)
	$(CC) -static-pie -o $@ $^

$(BUILD)/bin/slimfarmd: $(call obj,src/cmd/slimfarmd.c) $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $^ $(EXT_LIBS)

$(BUILD)/bin/slimfarm-sim: $(call obj,sim/slimfarm_sim.c) $(SIMLIB) $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $^ $(EXT_LIBS)

$(BUILD)/bench/bench_%: $(BUILD)/obj/tests/bench/bench_%.o $(SIMLIB) $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $^ $(EXT_LIBS)

$(BUILD)/tests/tools/%: $(BUILD)/obj/tests/tools/%.o
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $^

$(BUILD)/tests/test_fuzz_%: $(call obj,tests/fuzz/replay.c) $(BUILD)/obj/tests/fuzz/fuzz_%.o $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $^ $(EXT_LIBS)

$(BUILD)/tests/test_%: $(BUILD)/obj/tests/unit/test_%.o $(call obj,tests/t.c) $(SIMLIB) $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $< $(call obj,tests/t.c) $(SIMLIB) $(LIB) $(EXT_LIBS)

# libFuzzer builds (clang), in their own object tree: the library once with
# coverage hooks (fuzzer-no-link), then one small link per target.
FUZZ_SAN := -O1 -g -fsanitize=address,undefined -fno-sanitize-recover=all
build/fuzz/obj/%.o: %.c
	@mkdir -p $(dir $@)
	@$(if $(V),,echo "  FUZZ  $<")
	$(Q)$(FUZZCC) -std=c11 -D_GNU_SOURCE $(FUZZ_SAN) -fsanitize=fuzzer-no-link \
		-include src/base/compat.h $(EXT_CFLAGS) -c $< -o $@
build/fuzz/obj/%.o: %.cpp
	@mkdir -p $(dir $@)
	$(Q)clang++-14 -std=c++14 -D_GNU_SOURCE $(FUZZ_SAN) -fsanitize=fuzzer-no-link $(EXT_CFLAGS) -c $< -o $@
build/fuzz/obj/gen/web_assets.o: build/gen/web_assets.c
	@mkdir -p $(dir $@)
	$(Q)$(FUZZCC) -std=c11 -D_GNU_SOURCE $(FUZZ_SAN) -include src/base/compat.h -I. $(EXT_CFLAGS) \
		-c $< -o $@
build/fuzz/libslimfarm.a: $(patsubst %,build/fuzz/obj/%.o,$(basename $(LIB_C) $(LIB_CXX))) \
		build/fuzz/obj/gen/web_assets.o
	rm -f $@ && ar rcs $@ $^
build/fuzz/fuzz_%: build/fuzz/obj/tests/fuzz/fuzz_%.o build/fuzz/libslimfarm.a
	$(FUZZCC) $(FUZZ_SAN) -fsanitize=fuzzer -o $@ $^ $(EXT_LIBS)
fuzzers: $(FUZZERS)

# The dashboard's browser test drives Debian's chromium with playwright-core,
# installed from the committed lock file only when missing (never a browser
# download: PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD).  Debian's nodejs ships npm
# apart.
BROWSER_NODE := tests/browser/node_modules/playwright-core/package.json
$(BROWSER_NODE): tests/browser/package.json tests/browser/package-lock.json
	@command -v npm >/dev/null || DEBIAN_FRONTEND=noninteractive apt-get install -y -q npm >/dev/null
	cd tests/browser && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --no-audit --no-fund --loglevel=error
	@touch $@
browser-deps: $(BROWSER_NODE)

FUZZ_RUNS ?= 3000
# Tests at once (tests/run.sh; empty: one per core); JOBS=1 runs them one by one.
JOBS ?=
check: deps
	@missing=$$($(call MISSING,$(CHECK_OPT_PKGS))); \
	if [ -n "$$missing" ]; then \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -q $$missing >/dev/null 2>&1 || \
			echo "make check: could not install $$missing; the tests that need it skip"; \
	fi
	$(MAKE) --no-print-directory browser-deps
	$(MAKE) --no-print-directory SAN=1 tests
	$(MAKE) --no-print-directory all
	$(MAKE) --no-print-directory fuzzers
	$(MAKE) --no-print-directory check-layers check-size check-format check-headers
	FUZZ_RUNS=$(FUZZ_RUNS) JOBS=$(JOBS) tests/run.sh build/san $(T)

# The store and the farm on both engines (issue 32): the unit programs that open a store
# (store, farm, API, history, metrics, web) on SQLite, and tests/integ/store_pg.sh, which
# starts a PostgreSQL server of its own (initdb into a temp dir, a Unix socket) and runs
# them on it; the daemon as three hosts on one PostgreSQL (tests/integ/farmd_hosts*.sh);
# then every daemon scenario on PostgreSQL (tests/integ/farmd_pg.sh, FARMD_PG_TESTS=all,
# JOBS at a time: 29 scenarios in 25 min one at a time, load 20-40 on two cores).  On SQLite the scenarios are make check's,
# which runs farmd_pg's three of them on PostgreSQL too.  Not in check: its time.
PG_UNITS := test_sqldb test_store test_farm test_api test_history test_metrics test_web
check-pg: deps
	$(MAKE) --no-print-directory SAN=1 tests
	JOBS=$(JOBS) tests/run.sh build/san "$(PG_UNITS) store_pg store_hosts sqldb_conn farmd_hosts"
	FARMD_PG_TESTS=all JOBS=$(JOBS) BUILD=build/san bash tests/integ/farmd_pg.sh

# Issue 32's acceptance run alone (tests/integ/farmd_hosts_chaos.sh, also in check): three
# hosts, twelve printers, forty jobs; a host killed, a host cut off, the server stopped for 30 s.
check-chaos: deps
	$(MAKE) --no-print-directory SAN=1 tests
	tests/run.sh build/san farmd_hosts_chaos

T ?=
SECS ?= 60
fuzz: deps
	@test -n "$(T)" || { echo "usage: make fuzz T=NAME [SECS=60]  (NAME from tests/fuzz/fuzz_NAME.c)"; exit 2; }
	$(MAKE) --no-print-directory build/fuzz/fuzz_$(T)
	mkdir -p build/fuzz/corpus-$(T) && build/fuzz/fuzz_$(T) -max_total_time=$(SECS) \
		-dict=tests/fuzz/$(T).dict build/fuzz/corpus-$(T) tests/fuzz/corpus/$(T)

demo: deps all
	tests/demo.sh $(if $(ONCE),--once)

bench: deps all $(BENCHES)
	@missing=$$($(call MISSING,$(BENCH_PKGS))); \
	if [ -n "$$missing" ]; then apt-get install -y -q $$missing >/dev/null; fi
	tests/bench/run.sh $(BUILD)

# Long runs on simulated time and many daemon kills (tests/bench/soak.sh); minutes, not in check.
soak: deps all $(BUILD)/bench/bench_soak
	tests/bench/soak.sh $(BUILD)

deps:
	@missing=$$($(call MISSING,$(DEB_PKGS))); \
	if [ -n "$$missing" ]; then \
		echo "installing: $$missing"; \
		export DEBIAN_FRONTEND=noninteractive; \
		apt-get update -q >/dev/null && apt-get install -y -q $$missing >/dev/null || \
			{ echo "make deps: could not install $$missing (run as root?)"; exit 1; }; \
	fi

install: all
	install -d $(DESTDIR)$(PREFIX)/bin $(DESTDIR)$(PREFIX)/libexec/slimfarm \
		$(DESTDIR)$(PREFIX)/share/slimfarm
	install -m 755 $(PROGS) $(DESTDIR)$(PREFIX)/bin/
	install -m 755 $(CMD_PROGS) $(DESTDIR)$(PREFIX)/libexec/slimfarm/
	cp -r config $(DESTDIR)$(PREFIX)/share/slimfarm/

SRC_ALL = $(shell git ls-files '*.c' '*.h' '*.cpp' 2>/dev/null)
format:
	clang-format -i $(SRC_ALL)
check-format:
	@clang-format --dry-run --Werror $(SRC_ALL) && echo "every source is clang-formatted (make format)"
check-headers:
	@for h in $(filter %.h,$(SRC_ALL)); do \
		echo '#include "'$$h'"' | $(CC) -std=c11 -D_GNU_SOURCE -I. $(EXT_CFLAGS) -fsyntax-only -x c - || exit 1; \
	done; echo "every header compiles alone"
check-layers:
	@tests/check-layers.sh
# One job per file: no source over 1000 lines, no function over 120 (--report: the longest).
check-size:
	@tests/check-size.sh

clean:
	rm -rf build bin

-include $(shell find build -name '*.d' 2>/dev/null)

