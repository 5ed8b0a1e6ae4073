# poromech on Debian 12 with Python 3.12: the environment pinned in constraints.txt, runtime
# dependencies only, the default scene's forms compiled in. Needs BuildKit (Docker >= 23's default).
#
#   docker build -t poromech .                        # runtime image (the last stage)
#   docker build -t poromech:test --target test .     # + test extras: docker run --rm poromech:test
#   docker run --rm --user "$(id -u):$(id -g)" -v "$PWD":/work poromech \
#       run /work/configs/sneddon.yaml -o /work/results/sneddon
#
# docs/docker.md explains the choices and records the last scripts/docker_check.sh run.

# The official python:3.12-slim-bookworm, pinned by its multi-platform index digest
# (docs/docker.md says where it comes from and how to update it). Where Docker Hub cannot be
# reached, scripts/docker_check.sh passes a local stand-in: --build-arg PYTHON_IMAGE=...
ARG PYTHON_IMAGE=python:3.12-slim-bookworm@sha256:0f5b26b9518d002b6173fd61daad821fa340635ebfec5bba471013f9ca114579

# ---- base: system packages and environment shared by all stages
FROM ${PYTHON_IMAGE} AS base
# gcc, libc6-dev: DOLFINx compiles each form to C at run time (FFCx + cffi).
# The X11/GL libraries and libgomp are run-time dependencies of the gmsh wheel. gmsh links libGL
# but only meshes here, never draws: a stub package stands for Mesa's GLX driver, which would
# bring the DRI drivers and LLVM (~200 MB).
RUN mkdir -p /tmp/stub/DEBIAN \
    && printf '%s\n' 'Package: poromech-no-gl-driver' 'Version: 1.0' 'Architecture: all' \
       'Maintainer: poromech' 'Provides: libglx-mesa0' \
       'Description: no OpenGL driver: gmsh links libGL but only meshes' >/tmp/stub/DEBIAN/control \
    && dpkg-deb --build /tmp/stub /tmp/stub.deb >/dev/null && dpkg -i /tmp/stub.deb \
    && rm -rf /tmp/stub /tmp/stub.deb \
    && apt-get update \
    && apt-get install -y --no-install-recommends gcc libc6-dev \
       libglu1-mesa libgl1 libxrender1 libxcursor1 libxft2 libxinerama1 libgomp1 libfontconfig1 \
    && rm -rf /var/lib/apt/lists/*
# MPIR_CVAR_CH4_CMA_ENABLE=0: MPICH's shared-memory transfers without process_vm_readv, which
# Docker's default seccomp profile forbids (mpirun -n 2 would die). HOME and the FEniCS JIT cache
# ($XDG_CACHE_HOME/fenics) are world-writable, so that any --user uid can run the image.
# The image runs as the unprivileged user poromech (uid 1000) by default, so that outputs on a bind
# mount are not owned by root; any other --user uid works as well.
ENV MPIR_CVAR_CH4_CMA_ENABLE=0 \
    HOME=/home/poromech \
    XDG_CACHE_HOME=/home/poromech/.cache \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1
RUN useradd --uid 1000 --user-group --no-create-home --home-dir "$HOME" --shell /bin/bash poromech \
    && mkdir -p "$XDG_CACHE_HOME" && chmod -R 1777 "$HOME"

# ---- build: /opt/venv with the runtime dependencies, every version from constraints.txt.
# Pip's CA bundle, where a machine needs one, is a build secret (never stored in a layer):
#   docker build --secret id=pip_cert,src=/path/to/ca-bundle.crt ...
FROM base AS build
WORKDIR /src
COPY pyproject.toml constraints.txt ./
RUN --mount=type=secret,id=pip_cert \
    if [ -s /run/secrets/pip_cert ]; then export PIP_CERT=/run/secrets/pip_cert; fi \
    && python3.12 -m venv /opt/venv \
    && /opt/venv/bin/pip install --quiet -c constraints.txt pip setuptools \
    && python3.12 -c 'import tomllib; print(*tomllib.load(open("pyproject.toml", "rb"))["project"]["dependencies"], sep="\n")' > requirements.txt \
    && /opt/venv/bin/pip install --quiet -c constraints.txt -r requirements.txt
COPY . .
RUN /opt/venv/bin/pip install --quiet --no-deps --no-build-isolation . \
    && /opt/venv/bin/pip check \
    && cp scripts/dolfinx_mpi_first.pth \
       "$(/opt/venv/bin/python -c 'import sysconfig; print(sysconfig.get_path("purelib"))')/"

# ---- runtime: the venv, and the default scene's forms compiled into $XDG_CACHE_HOME/fenics
FROM base AS runtime
COPY --from=build /opt/venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
# Runs whatever `poromech run` runs by default, cheaply (one step) into a throwaway directory:
# the compiled forms do not depend on the number of steps.
ARG PRECOMPILE_ARGS="--set time.steps=1"
RUN poromech run ${PRECOMPILE_ARGS} -q -o /tmp/precompile \
    && rm -rf /tmp/precompile \
    && chmod -R a+rwX "$XDG_CACHE_HOME" \
    && mkdir -p /work && chmod 1777 /work
WORKDIR /work
USER poromech
ENTRYPOINT ["poromech"]
CMD ["run"]

# ---- test: the runtime image plus the source tree and the test extras (pytest)
FROM runtime AS test
USER root
WORKDIR /opt/poromech
COPY . .
RUN --mount=type=secret,id=pip_cert \
    if [ -s /run/secrets/pip_cert ]; then export PIP_CERT=/run/secrets/pip_cert; fi \
    && pip install --quiet -c constraints.txt --no-build-isolation -e ".[test]" \
    && chmod -R a+rwX /opt/poromech
USER poromech
ENTRYPOINT []
CMD ["python", "-m", "pytest"]

# ---- the default target: the runtime image
FROM runtime
