"""Where the OpenCL sources live (repo checkout or installed package)."""
from pathlib import Path


def cl_dir() -> Path:
    here = Path(__file__).resolve().parent
    for cand in (here.parent / "cl", here / "cl"):
        if (cand / "common.h").is_file():
            return cand
    raise FileNotFoundError(f"OpenCL sources (cl/common.h) not found beside {here}")
