# cython: language_level=3
"""Build probe: proves the kernel toolchain compiled and loads (doctor, check-arm64)."""


def abi_version() -> int:
    """Version of the kernels' calling conventions; bumped when a kernel's signature changes."""
    return 1
