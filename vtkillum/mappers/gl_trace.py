"""Count the OpenGL calls a VTK render makes: texture uploads, shader builds, read-backs.

VTK (9.3 and later) calls OpenGL through function pointers that its loader (glad)
fills in when a context is made current for the first time; they are exported by
``libvtkglad`` as ``vtk_glad_gl<Name>``. :class:`GLCallCounter` swaps a few of these
pointers for ctypes callbacks that count the call (and the bytes of a texture upload)
and then call the driver's function, whatever the driver (OSMesa llvmpipe, EGL on a GPU,
GLX). Counting is exact and deterministic: it is what VTK asked OpenGL to do, not a
timing.

Used by ``tests/rendering/test_opengl_host_work.py`` (a camera move must not re-upload a
volume or rebuild the shader) and ``benchmarks/bench_opengl.py`` (uploads per frame);
:func:`gl_function` gives any OpenGL call VTK's loader holds (used by
:mod:`vtkillum.mappers.texture_upload`).

Limits: the pointers are swapped in the process; a context created afterwards whose
loader runs again (a new window in a process that had none) overwrites them, so
:meth:`GLCallCounter.start` must follow the window's first render. The callbacks hold
the GIL for a few microseconds per call; only calls that a frame makes a handful of
times are wrapped (not draws or uniform updates).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import os
from collections import Counter

from typing_extensions import Self

# GL enums used to size uploads.
_TYPE_BYTES = {0x1401: 1, 0x1400: 1, 0x1403: 2, 0x1402: 2, 0x1405: 4, 0x1404: 4, 0x1406: 4,
               0x140B: 2}  # ubyte, byte, ushort, short, uint, int, float, half
_FORMAT_COMPONENTS = {0x1903: 1, 0x1909: 1, 0x8227: 2, 0x1907: 3, 0x1908: 4, 0x80E0: 3,
                      0x80E1: 4, 0x8D94: 1, 0x8228: 2, 0x8D98: 3, 0x8D99: 4, 0x1906: 1,
                      0x1902: 1}  # RED, LUMINANCE, RG, RGB, RGBA, BGR, BGRA, RED_INTEGER, ...

_u = ctypes.c_uint
_i = ctypes.c_int
_p = ctypes.c_void_p
_sz = ctypes.c_ssize_t

#: name -> (argument types, index of (width, height, depth, format, type) or None)
SIGNATURES = {
    "glTexImage3D": ((_u, _i, _i, _i, _i, _i, _i, _u, _u, _p), (3, 4, 5, 7, 8)),
    "glTexSubImage3D": ((_u, _i, _i, _i, _i, _i, _i, _i, _u, _u, _p), (5, 6, 7, 8, 9)),
    "glTexImage2D": ((_u, _i, _i, _i, _i, _i, _u, _u, _p), (3, 4, None, 6, 7)),
    "glTexSubImage2D": ((_u, _i, _i, _i, _i, _i, _u, _u, _p), (4, 5, None, 6, 7)),
    "glTexImage1D": ((_u, _i, _i, _i, _i, _u, _u, _p), (3, None, None, 5, 6)),
    "glTexSubImage1D": ((_u, _i, _i, _i, _u, _u, _p), (3, None, None, 4, 5)),
    "glCompileShader": ((_u,), None),
    "glLinkProgram": ((_u,), None),
    "glReadPixels": ((_i, _i, _i, _i, _u, _u, _p), (2, 3, None, 4, 5)),
    "glFinish": ((), None),
    "glGenTextures": ((_i, _p), None),
    "glDeleteTextures": ((_i, _p), None),
    "glBufferData": ((_u, _sz, _p, _u), None),
}

#: Calls that upload texels (3D: volumes; 1D/2D: transfer-function tables, depth copies).
UPLOADS = ("glTexImage3D", "glTexSubImage3D", "glTexImage2D", "glTexSubImage2D",
           "glTexImage1D", "glTexSubImage1D")


@functools.lru_cache(maxsize=1)
def _glad_library():
    import vtkmodules

    folder = os.path.dirname(vtkmodules.__file__)
    for path in sorted(glob.glob(os.path.join(folder, "libvtkglad*.so*"))) + \
            sorted(glob.glob(os.path.join(folder, "..", "vtk.libs", "libvtkglad*"))):
        return ctypes.CDLL(path)
    name = ctypes.util.find_library("vtkglad")
    if name is None:
        raise RuntimeError("libvtkglad not found: this VTK does not load OpenGL through glad")
    return ctypes.CDLL(name)


def gl_function(name: str, restype, *argtypes):
    """A callable for the OpenGL function ``name`` as VTK's loader holds it (``restype``,
    ``argtypes``: ctypes types). The pointer is read at each call: a context made current
    later, or a :class:`GLCallCounter`, may have swapped it. Call it only while a VTK
    window's context is current (e.g. in a mapper's render events)."""
    slot = ctypes.c_void_p.in_dll(_glad_library(), f"vtk_glad_{name}")
    proto = ctypes.CFUNCTYPE(restype, *argtypes)

    def call(*args):
        if not slot.value:
            raise RuntimeError(f"{name} is not loaded: no OpenGL context was made current")
        return proto(slot.value)(*args)
    return call


class GLCallCounter:
    """Count selected OpenGL calls (see the module docstring).

    Attributes
    ----------
    calls : Counter
        ``name -> calls`` since :meth:`start` or the last :meth:`reset`.
    bytes : Counter
        ``name -> texel bytes`` of the upload calls (host pointers, pixel buffers and
        allocations without data alike) and read back by ``glReadPixels``.
    uploads_3d : list of tuple
        ``(width, height, depth, internal format or None, bytes)`` of each 3D upload.

    Examples
    --------
    >>> window.Render()                 # the loader runs at the first render
    >>> with GLCallCounter() as gl:
    ...     window.Render()
    >>> gl.calls["glTexImage3D"]
    0
    """

    def __init__(self, names=tuple(SIGNATURES)) -> None:
        self.names = tuple(names)
        self.calls = Counter()
        self.bytes = Counter()
        self.uploads_3d = []
        self._saved = {}
        self._callbacks = {}

    def reset(self) -> None:
        self.calls.clear()
        self.bytes.clear()
        self.uploads_3d.clear()

    def start(self) -> GLCallCounter:
        """Swap the pointers (after the window's first render: the loader has run)."""
        lib = _glad_library()
        for name in self.names:
            argtypes, sizes = SIGNATURES[name]
            slot = ctypes.c_void_p.in_dll(lib, f"vtk_glad_{name}")
            original = slot.value
            if not original:
                continue  # not loaded (no context yet, or not offered by the driver)
            proto = ctypes.CFUNCTYPE(None, *argtypes)
            real = proto(original)
            callback = proto(self._wrap(name, real, sizes))
            self._saved[name] = (slot, original, real)
            self._callbacks[name] = callback
            slot.value = ctypes.cast(callback, ctypes.c_void_p).value
        return self

    def stop(self) -> None:
        """Put the driver's pointers back."""
        for slot, original, _ in self._saved.values():
            slot.value = original
        self._saved.clear()
        self._callbacks.clear()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _wrap(self, name, real, sizes):
        def call(*args):
            self.calls[name] += 1
            if sizes is not None:
                w, h, d, fmt, typ = (1 if k is None else args[k] for k in sizes)
                n = int(w) * int(h) * int(d) * _FORMAT_COMPONENTS.get(int(fmt), 4) * \
                    _TYPE_BYTES.get(int(typ), 4)
                self.bytes[name] += n
                if name in ("glTexImage3D", "glTexSubImage3D"):
                    internal = args[2] if name == "glTexImage3D" else None
                    self.uploads_3d.append((int(w), int(h), int(d), internal, n))
            real(*args)
        return call

    # --- summaries -------------------------------------------------------------------------------
    @property
    def texture_uploads(self) -> int:
        """Calls that upload texels (any dimension)."""
        return sum(self.calls[n] for n in UPLOADS)

    @property
    def volume_uploads(self) -> int:
        """3D texture uploads (volumes and illumination grids)."""
        return self.calls["glTexImage3D"] + self.calls["glTexSubImage3D"]

    @property
    def shader_builds(self) -> int:
        """Programs linked (a rebuilt shader links once)."""
        return self.calls["glLinkProgram"]

    def summary(self) -> dict:
        return {"texture uploads": self.texture_uploads, "3D uploads": self.volume_uploads,
                "3D bytes": self.bytes["glTexImage3D"] + self.bytes["glTexSubImage3D"],
                "shader builds": self.shader_builds, "read-backs": self.calls["glReadPixels"],
                "glFinish": self.calls["glFinish"]}


__all__ = ["SIGNATURES", "UPLOADS", "GLCallCounter", "gl_function"]
