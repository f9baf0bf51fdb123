"""Screen grabs and a clean window close on an X server, with ctypes only.

Used by the GUI tests and the screenshot script to photograph the whole ParaView
window (panels included, which ``SaveScreenshot`` leaves out) and to close it the
way a window manager would (``WM_DELETE_WINDOW``), so that ParaView exits through
its normal shutdown and its exit status means something. Needs only ``libX11``
(a dependency of ParaView itself); no ImageMagick, xwd or xdotool.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import struct
import zlib

import numpy as np

_ZPIXMAP = 2
_ALL_PLANES = 0xFFFFFFFF
_CLIENT_MESSAGE = 33


class _XImage(ctypes.Structure):
    # Only the leading fields are read; the function pointers at the end are not.
    _fields_ = [("width", ctypes.c_int), ("height", ctypes.c_int), ("xoffset", ctypes.c_int),
                ("format", ctypes.c_int), ("data", ctypes.POINTER(ctypes.c_ubyte)),
                ("byte_order", ctypes.c_int), ("bitmap_unit", ctypes.c_int),
                ("bitmap_bit_order", ctypes.c_int), ("bitmap_pad", ctypes.c_int),
                ("depth", ctypes.c_int), ("bytes_per_line", ctypes.c_int),
                ("bits_per_pixel", ctypes.c_int), ("red_mask", ctypes.c_ulong),
                ("green_mask", ctypes.c_ulong), ("blue_mask", ctypes.c_ulong)]


class _XClientMessageEvent(ctypes.Structure):
    _fields_ = [("type", ctypes.c_int), ("serial", ctypes.c_ulong), ("send_event", ctypes.c_int),
                ("display", ctypes.c_void_p), ("window", ctypes.c_ulong),
                ("message_type", ctypes.c_ulong), ("format", ctypes.c_int),
                ("data", ctypes.c_long * 5)]


class _XEvent(ctypes.Union):
    _fields_ = [("xclient", _XClientMessageEvent), ("pad", ctypes.c_long * 24)]


def _xlib():
    name = ctypes.util.find_library("X11") or "libX11.so.6"
    lib = ctypes.CDLL(name)
    lib.XOpenDisplay.restype = ctypes.c_void_p
    lib.XOpenDisplay.argtypes = [ctypes.c_char_p]
    lib.XDefaultRootWindow.restype = ctypes.c_ulong
    lib.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
    lib.XGetImage.restype = ctypes.POINTER(_XImage)
    lib.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int,
                              ctypes.c_uint, ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]
    lib.XGetGeometry.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.POINTER(ctypes.c_ulong)]\
        + [ctypes.POINTER(ctypes.c_int)] * 2 + [ctypes.POINTER(ctypes.c_uint)] * 4
    lib.XQueryTree.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.POINTER(ctypes.c_ulong),
                               ctypes.POINTER(ctypes.c_ulong),
                               ctypes.POINTER(ctypes.POINTER(ctypes.c_ulong)),
                               ctypes.POINTER(ctypes.c_uint)]
    lib.XFetchName.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.POINTER(ctypes.c_char_p)]
    lib.XInternAtom.restype = ctypes.c_ulong
    lib.XInternAtom.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int]
    lib.XSendEvent.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_long,
                               ctypes.POINTER(_XEvent)]
    lib.XGetWindowAttributes.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_void_p]
    lib.XFree.argtypes = [ctypes.c_void_p]
    lib.XDestroyImage = None  # a macro in Xlib; the image is freed through XFree below
    lib.XMoveResizeWindow.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int,
                                      ctypes.c_int, ctypes.c_uint, ctypes.c_uint]
    lib.XCloseDisplay.argtypes = [ctypes.c_void_p]
    lib.XFlush.argtypes = [ctypes.c_void_p]
    return lib


class Display:
    """A connection to ``$DISPLAY`` (or ``name``)."""

    def __init__(self, name: str | None = None) -> None:
        self.lib = _xlib()
        target = (name or os.environ.get("DISPLAY", "")).encode() or None
        self.handle = self.lib.XOpenDisplay(target)
        if not self.handle:
            raise RuntimeError(f"cannot open X display {name or os.environ.get('DISPLAY')!r}")
        self.root = self.lib.XDefaultRootWindow(self.handle)

    def close(self) -> None:
        if self.handle:
            self.lib.XCloseDisplay(self.handle)
            self.handle = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def geometry(self, window: int) -> tuple[int, int, int, int]:
        """(x, y, width, height) of ``window`` relative to its parent."""
        root = ctypes.c_ulong()
        x, y = ctypes.c_int(), ctypes.c_int()
        w, h, border, depth = (ctypes.c_uint() for _ in range(4))
        self.lib.XGetGeometry(self.handle, window, ctypes.byref(root), ctypes.byref(x),
                              ctypes.byref(y), ctypes.byref(w), ctypes.byref(h),
                              ctypes.byref(border), ctypes.byref(depth))
        return x.value, y.value, w.value, h.value

    def grab(self, window: int | None = None) -> np.ndarray:
        """RGB uint8 image (H, W, 3) of ``window`` (default the whole screen)."""
        window = self.root if window is None else window
        _, _, width, height = self.geometry(window)
        image = self.lib.XGetImage(self.handle, window, 0, 0, width, height, _ALL_PLANES, _ZPIXMAP)
        if not image:
            raise RuntimeError("XGetImage failed")
        try:
            img = image.contents
            if img.bits_per_pixel != 32:
                raise RuntimeError(f"unsupported X image format: {img.bits_per_pixel} bits/pixel")
            raw = ctypes.string_at(img.data, img.bytes_per_line * img.height)
            pixels = np.frombuffer(raw, dtype=np.uint8).reshape(img.height, img.bytes_per_line)
            pixels = pixels[:, : 4 * img.width].reshape(img.height, img.width, 4)
            # ZPixmap, 24-bit TrueColor in 32 bits, little-endian: B G R x.
            return np.ascontiguousarray(pixels[..., 2::-1])
        finally:
            self.lib.XFree(img.data)
            self.lib.XFree(image)

    def top_level_windows(self) -> list[tuple[int, str]]:
        """(window id, WM_NAME) of the root window's mapped children that have a name."""
        root, parent = ctypes.c_ulong(), ctypes.c_ulong()
        children = ctypes.POINTER(ctypes.c_ulong)()
        count = ctypes.c_uint()
        self.lib.XQueryTree(self.handle, self.root, ctypes.byref(root), ctypes.byref(parent),
                            ctypes.byref(children), ctypes.byref(count))
        found = []
        for i in range(count.value):
            window = children[i]
            name = ctypes.c_char_p()
            if self.lib.XFetchName(self.handle, window, ctypes.byref(name)) and name.value:
                found.append((window, name.value.decode(errors="replace")))
        if children:
            self.lib.XFree(children)
        return found

    def find_window(self, title_part: str) -> int | None:
        """The largest top-level window whose title contains ``title_part``."""
        matches = [(self.geometry(w)[2] * self.geometry(w)[3], w)
                   for w, name in self.top_level_windows() if title_part in name]
        return max(matches)[1] if matches else None

    def move_resize(self, window: int, x: int, y: int, width: int, height: int) -> None:
        """Place and size a top-level window (no window manager runs under Xvfb)."""
        self.lib.XMoveResizeWindow(self.handle, window, x, y, width, height)
        self.lib.XFlush(self.handle)

    def request_close(self, window: int) -> None:
        """Ask ``window`` to close, as a window manager does (``WM_DELETE_WINDOW``)."""
        protocols = self.lib.XInternAtom(self.handle, b"WM_PROTOCOLS", 0)
        delete = self.lib.XInternAtom(self.handle, b"WM_DELETE_WINDOW", 0)
        event = _XEvent()
        event.xclient.type = _CLIENT_MESSAGE
        event.xclient.window = window
        event.xclient.message_type = protocols
        event.xclient.format = 32
        event.xclient.data[0] = delete
        event.xclient.data[1] = 0  # CurrentTime
        self.lib.XSendEvent(self.handle, window, 0, 0, ctypes.byref(event))
        self.lib.XFlush(self.handle)


def write_png(path, rgb: np.ndarray) -> None:
    """Write an RGB uint8 (H, W, 3) array as PNG (zlib only, no imaging library)."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    height, width, _ = rgb.shape
    rows = b"".join(b"\x00" + rgb[y].tobytes() for y in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    png = (b"\x89PNG\r\n\x1a\n"
           + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(rows, 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)
