# Reproducible poromech image: Debian 12 with Python 3.12, installed by the README's steps.
#   docker build -t poromech .
#   docker run --rm -v "$PWD":/work poromech run /work/scene.yaml -o /work/results
FROM python:3.12-slim-bookworm

# make for the set-up; the X11/GL libraries are run-time dependencies of the gmsh wheel
RUN apt-get update \
    && apt-get install -y --no-install-recommends make libglu1-mesa libgl1 libxrender1 \
       libxcursor1 libxft2 libxinerama1 libgomp1 libfontconfig1 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/poromech
COPY . .
RUN make install PYTHON=python3.12 && rm -rf /root/.cache/pip
ENV PATH="/opt/poromech/.venv/bin:${PATH}"

WORKDIR /work
ENTRYPOINT ["poromech"]
CMD ["run", "-o", "/work/results"]
