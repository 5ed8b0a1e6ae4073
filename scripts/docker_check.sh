#!/usr/bin/env bash
# Build the poromech image and check that it runs what the README says:
#   * the runtime image builds, from the pinned python:3.12-slim-bookworm or, where Docker Hub
#     cannot be reached, from a local stand-in for it (built here, see build_standin);
#   * without --user it runs as the unprivileged user poromech (uid 1000), not as root;
#   * as a non-root --user, with the working directory bind-mounted at /work: the default scene
#     (its forms must come from the image's cache: none compiled at run time), a mechanics scene
#     (configs/sneddon.yaml, fractures.csv compared with a native run), a flow scene
#     (configs/flemisch_case2.yaml) and mpirun -n 2 of the mechanics scene; the outputs must be
#     owned by that user;
#   * with --tests, the test target (pytest in the image).
# The result (date, commands, pass/fail, sizes, times) replaces the block between the
# docker_check markers of docs/docker.md (unless --no-record). Exit status 0 when all passed.
#
# Usage: scripts/docker_check.sh [--tests] [--no-record] [--rebuild-base]
# Environment:
#   DOCKER   the docker client (default docker; it needs BuildKit, see below)
#   IMAGE    image name to build (default poromech:check; the test target is IMAGE-test)
#   BASE     base image to build from instead of the Dockerfile's pinned default
#   NATIVE   poromech executable for the native comparison (default .venv/bin/poromech,
#            made with `make install` when missing)
#   PIP_CERT CA bundle for pip inside the build (default: pip's global.cert, if any), passed
#            as a build secret, never stored in the image
#   STANDIN_PYTHON  the CPython 3.12 (built with --enable-shared) copied into the stand-in
#            (default: python3.12 on PATH)
set -euo pipefail
cd "$(dirname "$0")/.."

IMAGE=${IMAGE:-poromech:check}
STANDIN=poromech-standin/python:3.12-slim-bookworm
RUN_TESTS=0 RECORD=1 REBUILD_BASE=0
for arg in "$@"; do
    case $arg in
        --tests) RUN_TESTS=1 ;;
        --no-record) RECORD=0 ;;
        --rebuild-base) REBUILD_BASE=1 ;;
        *) echo "usage: $0 [--tests] [--no-record] [--rebuild-base]" >&2; exit 2 ;;
    esac
done

# The Dockerfile needs BuildKit: Docker >= 23 has it through the buildx plugin, older clients
# (Debian 12's docker.io 20.10: DOCKER=/usr/bin/docker) have it built in.
DOCKER=${DOCKER:-docker}
export DOCKER_BUILDKIT=1
"$DOCKER" info >/dev/null 2>&1 || { echo "docker_check: no Docker engine answers ($DOCKER info)" >&2; exit 1; }
if ! "$DOCKER" buildx version >/dev/null 2>&1 \
    && (( $("$DOCKER" version -f '{{.Client.Version}}' | cut -d. -f1) >= 23 )); then
    echo "docker_check: $DOCKER has no buildx plugin (BuildKit): install it, or set DOCKER to a" \
        "client with BuildKit built in (Docker < 23, e.g. DOCKER=/usr/bin/docker)" >&2
    exit 1
fi

WORK=$(mktemp -d /tmp/docker_check.XXXXXX)
trap 'umount "$WORK/rootfs/proc" 2>/dev/null || true; rm -rf "$WORK"' EXIT
RESULTS=()   # markdown table rows
FAILED=0
log() { echo "docker_check: $*"; }
now() { date +%s.%N; }
secs() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$2"; }
size_mb() { "$DOCKER" image inspect -f '{{.Size}}' "$1" | awk '{printf "%.0f MB", $1 / 1e6}'; }
record() {  # record CHECK COMMAND RESULT TIME
    RESULTS+=("| $1 | \`$2\` | $3 | $4 |")
    case $3 in FAIL*) FAILED=1 ;; esac
    log "$1: $3 ($4)"
}

# ---- the stand-in for python:3.12-slim-bookworm: Debian 12 minbase + a CPython 3.12 in /usr/local
build_standin() {
    local root=$WORK/rootfs py prefix mirror
    py=${STANDIN_PYTHON:-$(command -v python3.12)}
    prefix=$("$py" -c 'import sys; print(sys.base_prefix)')
    "$py" -c 'import sys, sysconfig; assert sys.version_info[:2] == (3, 12) and sysconfig.get_config_var("Py_ENABLE_SHARED")' \
        || { echo "docker_check: $py is not a CPython 3.12 built with --enable-shared" >&2; exit 1; }
    if ! command -v debootstrap >/dev/null || ! command -v patchelf >/dev/null; then
        echo "docker_check: the stand-in needs debootstrap and patchelf (apt-get install debootstrap patchelf)" >&2
        exit 1
    fi
    mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
    log "building the stand-in $STANDIN: debootstrap minbase bookworm + $prefix as /usr/local"
    # The run-time libraries the official image keeps for its CPython build (not Tk: as there,
    # _tkinter is left without its libraries).
    debootstrap --variant=minbase \
        --include=ca-certificates,netbase,tzdata,libssl3,libsqlite3-0,libffi8,libuuid1,libbz2-1.0,liblzma5,zlib1g,libncursesw6,libreadline8,libexpat1,libtirpc3,libnsl2,libcrypt1 \
        bookworm "$root" "$mirror" >"$WORK/debootstrap.log" 2>&1 \
        || { tail -20 "$WORK/debootstrap.log" >&2; exit 1; }
    # Apt sources, dpkg path excludes and apt settings as in the official Debian slim images.
    rm -f "$root/etc/apt/sources.list"
    cat >"$root/etc/apt/sources.list.d/debian.sources" <<EOF
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm bookworm-updates
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg

Types: deb
URIs: http://deb.debian.org/debian-security
Suites: bookworm-security
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
    printf '%s\n' 'path-exclude /usr/share/doc/*' 'path-include /usr/share/doc/*/copyright' \
        'path-exclude /usr/share/groff/*' 'path-exclude /usr/share/info/*' \
        'path-exclude /usr/share/linda/*' 'path-exclude /usr/share/lintian/overrides/*' \
        'path-exclude /usr/share/locale/*' 'path-exclude /usr/share/man/*' \
        >"$root/etc/dpkg/dpkg.cfg.d/docker"
    printf '%s\n' 'Acquire::Languages "none";' 'APT::AutoRemove::SuggestsImportant "false";' \
        'Dir::Cache::pkgcache ""; Dir::Cache::srcpkgcache "";' >"$root/etc/apt/apt.conf.d/docker-slim"
    find "$root/usr/share/doc" -mindepth 2 ! -name copyright -type f -delete
    rm -rf "$root"/usr/share/{man,info,groff,linda,locale}/*
    # CPython, relocated to /usr/local: RUNPATH as the official build ($ORIGIN/../lib), build
    # paths in sysconfig and scripts rewritten, no byte code, no test suites, and a fresh pip
    # from ensurepip (nothing of this machine's site-packages).
    cp -a "$prefix/." "$root/usr/local/"
    find "$root/usr/local" -depth \( \( -type d \( -name test -o -name tests -o -name idle_test \
        -o -name __pycache__ \) \) -o \( -type f \( -name '*.pyc' -o -name 'libpython*.a' \) \) \) \
        -exec rm -rf {} +
    rm -rf "$root/usr/local/lib/python3.12/site-packages" "$root"/usr/local/bin/pip*
    mkdir "$root/usr/local/lib/python3.12/site-packages"
    # shellcheck disable=SC2016  # a literal $ORIGIN
    patchelf --set-rpath '$ORIGIN/../lib' "$root/usr/local/bin/python3.12"
    find "$root/usr/local/lib" -name '*.so*' -type f -exec patchelf --remove-rpath {} \;
    grep -rlIZ --exclude='*.so*' "$prefix" "$root/usr/local" | xargs -0 -r sed -i "s#$prefix#/usr/local#g"
    mount -t proc proc "$root/proc"
    chroot "$root" sh -ec >"$WORK/standin.log" 2>&1 '
        export PATH=/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8
        ldconfig
        apt-get update -qq && apt-get upgrade -y -qq >/dev/null
        rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin /var/cache/apt/archives/*.deb
        python3.12 -m ensurepip --default-pip >/dev/null
        ln -sfn pip3 /usr/local/bin/pip
        find /usr/local -depth -name __pycache__ -exec rm -rf {} +
        if find /usr/local -type f \( -name "*.so*" -o -perm -u+x \) ! -name "*tkinter*" -exec ldd {} \; 2>/dev/null \
            | grep "not found"; then exit 1; fi
        python3 -c "import ssl, sqlite3, ctypes, venv, lzma, bz2, zlib, uuid, readline, sysconfig; print(sysconfig.get_paths()[\"include\"])"
    ' || { tail -20 "$WORK/standin.log" >&2; umount "$root/proc"; exit 1; }
    umount "$root/proc"
    : >"$root/etc/resolv.conf"
    tar --numeric-owner -C "$root" -c . | "$DOCKER" import \
        --change 'ENV PATH=/usr/local/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
        --change 'ENV LANG=C.UTF-8' \
        --change "ENV PYTHON_VERSION=$("$py" -c 'import platform; print(platform.python_version())')" \
        --change 'CMD ["python3"]' - "$STANDIN" >/dev/null
    rm -rf "$root"
}

# ---- base image: BASE, else the Dockerfile's pinned one if it can be pulled, else the stand-in
PINNED=$(sed -n 's/^ARG PYTHON_IMAGE=//p' Dockerfile)
BASE_NOTE=""
if [[ -n ${BASE:-} ]]; then
    BASE_NOTE="\`$BASE\` (given)"
elif "$DOCKER" image inspect "$PINNED" >/dev/null 2>&1 || "$DOCKER" pull -q "$PINNED" >/dev/null 2>&1; then
    BASE=$PINNED BASE_NOTE="the pinned official \`$PINNED\`"
else
    BASE=$STANDIN
    if [[ $REBUILD_BASE == 1 ]] || ! "$DOCKER" image inspect "$BASE" >/dev/null 2>&1; then
        t0=$(now)
        build_standin
        record "build the stand-in base" "scripts/docker_check.sh --rebuild-base" \
            "pass, $(size_mb "$STANDIN")" "$(secs "$t0" "$(now)") s"
    fi
    BASE_NOTE="the local stand-in \`$STANDIN\` (Debian bookworm minbase +
CPython $("$DOCKER" run --rm "$BASE" python3 -c 'import platform; print(platform.python_version())') in /usr/local): the pinned official image could not be pulled here"
fi
log "base: $BASE"

# ---- build the runtime image (and the test target)
BUILD=("$DOCKER" build --network host --build-arg "PYTHON_IMAGE=$BASE")
cert=${PIP_CERT:-$(pip config get global.cert 2>/dev/null || true)}
[[ -n $cert && -s $cert ]] && BUILD+=(--secret "id=pip_cert,src=$cert")
t0=$(now)
if "${BUILD[@]}" -t "$IMAGE" . >"$WORK/build.log" 2>&1; then
    record "build runtime image" "docker build -t $IMAGE ." "pass, $(size_mb "$IMAGE")" "$(secs "$t0" "$(now)") s"
else
    tail -30 "$WORK/build.log" >&2
    record "build runtime image" "docker build -t $IMAGE ." "FAIL" "$(secs "$t0" "$(now)") s"
    exit 1
fi

# ---- the default user: unprivileged
t0=$(now)
who=$("$DOCKER" run --rm --entrypoint id "$IMAGE" -un 2>&1)/$("$DOCKER" run --rm --entrypoint id "$IMAGE" -u 2>&1)
if [[ $who == poromech/1000 ]]; then
    record "default user" "docker run --rm --entrypoint id $IMAGE" "pass, $who (not root)" "$(secs "$t0" "$(now)") s"
else
    record "default user" "docker run --rm --entrypoint id $IMAGE" "FAIL ($who)" "$(secs "$t0" "$(now)") s"
fi

# ---- runs as a non-root user on a bind-mounted working directory
uid=$(id -u) gid=$(id -g)
if [[ $uid == 0 ]]; then uid=1000 gid=1000; fi   # root would prove nothing about --user
mkdir -p "$WORK/work" && cp -r configs "$WORK/work/" && chown -R "$uid:$gid" "$WORK/work"
RUN=("$DOCKER" run --rm --user "$uid:$gid" -v "$WORK/work":/work)
run_check() {  # run_check NAME SHOWN_COMMAND LOG docker-run-arguments...: exit 0, outputs ours
    local name=$1 shown=$2 out=$3 t0 rc=0
    shift 3
    t0=$(now)
    "${RUN[@]}" "$@" >"$WORK/$out.log" 2>&1 || rc=$?
    LAST_TIME="$(secs "$t0" "$(now)") s"
    if [[ $rc != 0 ]]; then
        tail -20 "$WORK/$out.log" >&2
        record "$name" "$shown" "FAIL (exit $rc)" "$LAST_TIME"
        return 1
    fi
    if [[ -n $(find "$WORK/work/results" ! -uid "$uid" 2>/dev/null) ]]; then
        record "$name" "$shown" "FAIL (outputs not owned by $uid:$gid)" "$LAST_TIME"
        return 1
    fi
}

# The default scene by the image's default command (`poromech run` in /work), counting the forms
# compiled at run time: new C files in the FEniCS JIT cache, $XDG_CACHE_HOME/fenics.
name="default scene (the image's default command)"
shown="docker run --rm --user $uid:$gid -v \"\$PWD\":/work $IMAGE"
# shellcheck disable=SC2016  # expanded in the container
if run_check "$name" "$shown" default --entrypoint sh "$IMAGE" -c 'touch /tmp/t0 && poromech run \
        && echo "compiled at run time: $(find "$XDG_CACHE_HOME/fenics" -name "*.c" -newer /tmp/t0 | wc -l)"'; then
    n=$(sed -n 's/^compiled at run time: //p' "$WORK/default.log")
    if [[ $n == 0 ]]; then
        record "$name" "$shown" "pass, no form compiled at run time" "$LAST_TIME"
    else
        record "$name" "$shown" "FAIL ($n forms compiled at run time)" "$LAST_TIME"
    fi
fi
# The same with an empty JIT cache: what the precompiled forms save.
name="default scene, empty JIT cache"
if run_check "$name" "$shown" default_nocache -e XDG_CACHE_HOME=/tmp/cache "$IMAGE" \
    run -o /work/results/default_nocache; then
    record "$name" "docker run ... -e XDG_CACHE_HOME=/tmp/cache $IMAGE run" "pass (compiles its forms)" "$LAST_TIME"
fi

# Mechanics: fractures.csv against a native run of the same scene.
NATIVE=${NATIVE:-.venv/bin/poromech}
[[ -x $NATIVE ]] || make install >/dev/null
"$NATIVE" run configs/sneddon.yaml -q -o "$WORK/native_sneddon"
shown="docker run --rm --user $uid:$gid -v \"\$PWD\":/work $IMAGE run /work/configs/sneddon.yaml -o /work/results/sneddon"
if run_check "mechanics (Sneddon)" "$shown" sneddon "$IMAGE" run /work/configs/sneddon.yaml -o /work/results/sneddon; then
    if cmp -s "$WORK/native_sneddon/fractures.csv" "$WORK/work/results/sneddon/fractures.csv"; then
        record "mechanics (Sneddon)" "$shown" "pass, fractures.csv byte-identical to the native run" "$LAST_TIME"
    else
        diff=$(python3 - "$WORK/native_sneddon/fractures.csv" "$WORK/work/results/sneddon/fractures.csv" <<'EOF'
import csv, sys
a, b = ([[float(x) for x in row] for row in list(csv.reader(open(f)))[1:]] for f in sys.argv[1:])
scale = max(abs(x) for row in a for x in row) or 1.0
print("inf" if len(a) != len(b) else
      max(abs(x - y) for r, s in zip(a, b) for x, y in zip(r, s)) / scale)
EOF
)
        if python3 -c "import sys; sys.exit(not float(sys.argv[1]) <= 1e-10)" "$diff"; then
            record "mechanics (Sneddon)" "$shown" "pass, fractures.csv equal to the native run to $diff (relative)" "$LAST_TIME"
        else
            record "mechanics (Sneddon)" "$shown" "FAIL, fractures.csv differs from the native run ($diff)" "$LAST_TIME"
        fi
    fi
fi

# Flow.
shown="docker run --rm --user $uid:$gid -v \"\$PWD\":/work $IMAGE run /work/configs/flemisch_case2.yaml -o /work/results/flemisch_case2"
if run_check "flow (Flemisch case 2)" "$shown" flemisch_case2 "$IMAGE" run /work/configs/flemisch_case2.yaml -o /work/results/flemisch_case2; then
    record "flow (Flemisch case 2)" "$shown" "pass" "$LAST_TIME"
fi

# MPI: two ranks in one container.
shown="docker run --rm --user $uid:$gid -v \"\$PWD\":/work --entrypoint mpirun $IMAGE -n 2 poromech run /work/configs/sneddon.yaml -o /work/results/sneddon_np2"
if run_check "mpirun -n 2 (Sneddon)" "$shown" sneddon_np2 --entrypoint mpirun "$IMAGE" -n 2 poromech run /work/configs/sneddon.yaml -o /work/results/sneddon_np2; then
    ranks=$(python3 -c "import json, sys; print(json.load(open(sys.argv[1]))['mpi_ranks'])" "$WORK/work/results/sneddon_np2/summary.json")
    if [[ $ranks == 2 ]]; then
        record "mpirun -n 2 (Sneddon)" "$shown" "pass, 2 ranks" "$LAST_TIME"
    else
        record "mpirun -n 2 (Sneddon)" "$shown" "FAIL (summary.json: $ranks ranks)" "$LAST_TIME"
    fi
fi

# ---- the test target
if [[ $RUN_TESTS == 1 ]]; then
    t0=$(now)
    if "${BUILD[@]}" --target test -t "$IMAGE-test" . >"$WORK/build_test.log" 2>&1; then
        record "build test target" "docker build --target test -t $IMAGE-test ." "pass, $(size_mb "$IMAGE-test")" "$(secs "$t0" "$(now)") s"
        t0=$(now) rc=0
        "$DOCKER" run --rm --user "$uid:$gid" "$IMAGE-test" >"$WORK/pytest.log" 2>&1 || rc=$?
        summary=$(grep -E '^=+ .*(passed|failed|error).* =+$' "$WORK/pytest.log" | tail -1 | tr -d '=' | xargs)
        if [[ $rc == 0 ]]; then
            record "test suite in the image" "docker run --rm --user $uid:$gid $IMAGE-test" "pass: $summary" "$(secs "$t0" "$(now)") s"
        else
            tail -30 "$WORK/pytest.log" >&2
            record "test suite in the image" "docker run --rm --user $uid:$gid $IMAGE-test" "FAIL (exit $rc): $summary" "$(secs "$t0" "$(now)") s"
        fi
    else
        tail -30 "$WORK/build_test.log" >&2
        record "build test target" "docker build --target test -t $IMAGE-test ." "FAIL" "$(secs "$t0" "$(now)") s"
    fi
fi

# ---- report
VERDICT=$([[ $FAILED == 0 ]] && echo "all checks passed" || echo "SOME CHECKS FAILED")
{
    echo "Last run: $(date -u '+%Y-%m-%d %H:%M UTC'), \`$([[ $DOCKER != docker ]] && echo "DOCKER=$DOCKER ")scripts/docker_check.sh $*\` on $(nproc) cores,"
    echo "Docker $("$DOCKER" version -f '{{.Server.Version}}'), git $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet HEAD 2>/dev/null || echo ' + uncommitted changes'): **$VERDICT**."
    echo
    echo "Base: $BASE_NOTE; $(size_mb "$BASE")."
    echo "Runtime image \`$IMAGE\`: $(size_mb "$IMAGE")."
    echo "Runs as \`--user $uid:$gid\` on a bind-mounted working directory; times include container start."
    echo
    echo "| check | command | result | time |"
    echo "|---|---|---|---|"
    printf '%s\n' "${RESULTS[@]}"
} >"$WORK/report.md"
cat "$WORK/report.md"
if [[ $RECORD == 1 ]]; then
    python3 - docs/docker.md "$WORK/report.md" <<'EOF'
import sys
from pathlib import Path
doc, report = Path(sys.argv[1]), Path(sys.argv[2]).read_text()
begin, end = "<!-- docker_check: begin -->", "<!-- docker_check: end -->"
text = doc.read_text()
head, rest = text.split(begin, 1)
doc.write_text(head + begin + "\n" + report + rest[rest.index(end):])
EOF
    log "recorded in docs/docker.md"
fi
exit $FAILED
