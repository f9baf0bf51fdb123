"""Grids from a warp device straight into the 3D textures VTK made for them.

:class:`~vtkillum.mappers.illuminated_volume_mapper.IlluminatedVolume` hands its light
grids to VTK's ray caster as ``vtkImageData`` inputs (16-bit RGBA), and
:class:`~vtkillum.mappers.ambient_volume_mapper.AmbientScatteringVolume` its ``σ̃t`` and
radiance cache (float32, 1 and 4 components: :class:`TexelFormat`); VTK uploads each
from host memory when the image changes. For grids that a computation left on a GPU
that is a download, a pack on the host and an upload (1.45 s for a 512³ transmittance on
an H200, most of a TF edit). :class:`TextureWriter` writes the new texels into the textures VTK already
has instead, without touching the images:

1. VTK's texture of a port is found among all textures of the current context as the
   one texture of the grid's size and the port's format whose texels equal the port
   image's at 24 places, once the mapper has rendered since the image last changed (so
   VTK has made its own texture from it, and a texture of another volume with the same texels makes
   two: none is taken, the host path draws). Each texture found gets a debug label
   (``glObjectLabel``): OpenGL reuses the names of deleted textures, the label goes with
   the texture, so later writes find it again at once. (VTK's ``UpdateShaderEvent`` is
   no help: it comes only in frames that reuse the shader, before that frame binds its
   textures, and a window whose lights follow the camera, as pyvista's, rebuilds the
   shader in every frame.)
2. When the grids change (the pipeline update), each port gets a job if its image, or
   the texture found for it, has the grid's size.
3. At the start of the next render (``VolumeMapperRenderStartEvent``: after the inputs
   were updated, before the draw) the texture is checked (label, size, format) or found,
   the grid is packed on its device into texels kept per port (:mod:`vtkillum.core.texels`)
   and copied into an OpenGL pixel buffer (on CUDA through warp's CUDA–OpenGL interop,
   ``wp.RegisteredGLBuffer``: the buffer mapped into the GPU, no host copy; on the CPU
   device from host memory), and ``glTexSubImage3D`` copies the buffer into the texture.

Anything else (the first frame, a grid of another size, float32 textures, an OpenGL
error) takes the host path: the images are filled and VTK uploads them. After a direct
write the images are brought up to date in the background (the packed texels copied from
the device into the image arrays, without marking them modified, so VTK uploads nothing):
VTK reads them only when it makes its textures anew (a lost context, another window),
and then finds the grids it was last given. :meth:`TextureWriter.sync_host` waits for
that copy.

Measured on an NVIDIA H200 (``benchmarks/bench_opengl.py --interactive --tf-edit
--device-upload``, 512³ grids, 1024² window): a write takes 14 ms (pack 1.3 ms, CUDA
registration of the pixel buffer and copy 12 ms, ``glTexSubImage3D``); a TF edit to the new
frame 164–174 ms with a transmittance (1451 ms through the host), 102 ms with a photon
density (3014 ms), 462 ms with the ambient mapper's two grids (5.8 s), most of it the
frame. The pictures equal the host path's bit for bit there too. ``device_upload`` is on
by default in both mappers (:class:`DeviceUpload`).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

from vtkillum.mappers.gl_trace import gl_function

_u, _i, _p, _sz = ctypes.c_uint, ctypes.c_int, ctypes.c_void_p, ctypes.c_ssize_t

GL_TEXTURE_3D = 0x806F
GL_TEXTURE_BINDING_3D = 0x806A
GL_TEXTURE_WIDTH, GL_TEXTURE_HEIGHT, GL_TEXTURE_DEPTH = 0x1000, 0x1001, 0x8071
GL_TEXTURE_INTERNAL_FORMAT = 0x1003
GL_RGBA, GL_RGBA16, GL_UNSIGNED_SHORT = 0x1908, 0x805B, 0x1403
GL_RED, GL_FLOAT, GL_R32F, GL_RGBA32F = 0x1903, 0x1406, 0x822E, 0x8814
GL_PIXEL_UNPACK_BUFFER, GL_PIXEL_UNPACK_BUFFER_BINDING = 0x88EC, 0x88EF
GL_STREAM_DRAW = 0x88E0
GL_UNPACK_ALIGNMENT = 0x0CF5
GL_TEXTURE = 0x1702
GL_PIXEL_PACK_BUFFER, GL_PIXEL_PACK_BUFFER_BINDING = 0x88EB, 0x88ED


class _GL:
    """The OpenGL calls used here (looked up through VTK's loader)."""

    def __init__(self) -> None:
        self.GetIntegerv = gl_function("glGetIntegerv", None, _u, _p)
        self.BindTexture = gl_function("glBindTexture", None, _u, _u)
        self.IsTexture = gl_function("glIsTexture", ctypes.c_ubyte, _u)
        self.GenBuffers = gl_function("glGenBuffers", None, _i, _p)
        self.DeleteBuffers = gl_function("glDeleteBuffers", None, _i, _p)
        self.BindBuffer = gl_function("glBindBuffer", None, _u, _u)
        self.BufferData = gl_function("glBufferData", None, _u, _sz, _p, _u)
        self.TexSubImage3D = gl_function("glTexSubImage3D", None, _u, _i, _i, _i, _i, _i, _i, _i,
                                         _u, _u, _p)
        self.PixelStorei = gl_function("glPixelStorei", None, _u, _i)
        self.GetError = gl_function("glGetError", _u)
        self.GenTextures = gl_function("glGenTextures", None, _i, _p)
        self.DeleteTextures = gl_function("glDeleteTextures", None, _i, _p)
        self.GetTextureLevelParameteriv = gl_function("glGetTextureLevelParameteriv", None,
                                                      _u, _i, _u, _p)
        self.GetTextureSubImage = gl_function("glGetTextureSubImage", None, _u, _i, _i, _i, _i,
                                              _i, _i, _i, _u, _u, _i, _p)
        self.ObjectLabel = gl_function("glObjectLabel", None, _u, _u, _i, ctypes.c_char_p)
        self.GetObjectLabel = gl_function("glGetObjectLabel", None, _u, _u, _i, _p,
                                          ctypes.c_char_p)

    def label(self, texture: int) -> bytes:
        """The debug label of a texture name (empty for a texture made since)."""
        length, buffer = _i(0), ctypes.create_string_buffer(64)
        self.GetObjectLabel(GL_TEXTURE, texture, 64, ctypes.byref(length), buffer)
        return buffer.value

    def integer(self, name: int) -> int:
        value = _i(0)
        self.GetIntegerv(name, ctypes.byref(value))
        return value.value


@dataclass(frozen=True)
class TexelFormat:
    """How a port's texels look to VTK, to OpenGL and to warp."""

    internal_format: int  # of VTK's texture (what it makes from such an image)
    gl_format: int        # of the texels written (glTexSubImage3D)
    gl_type: int
    vtk_type: int         # of the image's array
    components: int
    dtype: str            # numpy / warp scalar: "uint16" or "float32"

    @property
    def itemsize(self) -> int:
        return np.dtype(self.dtype).itemsize

    def warp_dtype(self):
        import warp as wp

        return {"uint16": wp.uint16, "float32": wp.float32}[self.dtype]


#: 16-bit normalised RGBA: the light grids of IlluminatedVolume (VTK_UNSIGNED_SHORT = 5).
RGBA16 = TexelFormat(GL_RGBA16, GL_RGBA, GL_UNSIGNED_SHORT, 5, 4, "uint16")
#: One float32 component (VTK_FLOAT = 10): VTK makes GL_R32F.
R32F = TexelFormat(GL_R32F, GL_RED, GL_FLOAT, 10, 1, "float32")
#: Four float32 components: VTK makes GL_RGBA32F.
RGBA32F = TexelFormat(GL_RGBA32F, GL_RGBA, GL_FLOAT, 10, 4, "float32")


@dataclass
class Texture:
    """VTK's texture of one input port, as found by its texels."""

    name: int
    size: tuple  # (width, height, depth): the image's dimensions
    internal_format: int
    label: bytes  # the debug label given to it: gone once VTK deletes it (names are reused)


@dataclass
class Job:
    """Texels for one port: ``pack(out)`` fills a warp array of shape ``(depth, height,
    width * components)`` (``size`` is the texture's ``(width, height, depth)``; the
    port's :class:`TexelFormat`; the texture's texel order, width fastest) on ``device``
    (:mod:`vtkillum.core.texels`)."""

    size: tuple  # texture (width, height, depth)
    device: str
    pack: object


class PixelBuffer:
    """An OpenGL pixel buffer of ``nbytes`` filled from warp: mapped into CUDA on a GPU,
    from host memory on the CPU device.

    On CUDA the buffer is registered with CUDA for each fill and unregistered after it,
    while VTK's context is current: a registration that outlived the window's context
    could not be unregistered (CUDA error 219 when it is let go).
    """

    def __init__(self, gl: _GL, nbytes: int, device: str) -> None:
        self.gl, self.nbytes, self.device = gl, int(nbytes), str(device)
        name = _u(0)
        gl.GenBuffers(1, ctypes.byref(name))
        self.name = name.value
        gl.BindBuffer(GL_PIXEL_UNPACK_BUFFER, self.name)
        gl.BufferData(GL_PIXEL_UNPACK_BUFFER, self.nbytes, None, GL_STREAM_DRAW)
        gl.BindBuffer(GL_PIXEL_UNPACK_BUFFER, 0)

    def fill(self, texels) -> None:
        """Copy ``texels`` (a contiguous warp array of the buffer's size, on its device)
        into the buffer."""
        import warp as wp

        if self.device.startswith("cuda"):
            registered = wp.RegisteredGLBuffer(self.name, self.device,
                                               flags=wp.RegisteredGLBuffer.WRITE_DISCARD,
                                               fallback_to_copy=False)
            try:
                out = registered.map(dtype=texels.dtype, shape=texels.shape)
                try:
                    wp.copy(out, texels)
                finally:
                    registered.unmap()
            finally:
                del registered  # unregistered now, while the context is current
            return
        host = np.ascontiguousarray(texels.numpy())
        self.gl.BindBuffer(GL_PIXEL_UNPACK_BUFFER, self.name)
        self.gl.BufferData(GL_PIXEL_UNPACK_BUFFER, self.nbytes,
                           host.ctypes.data_as(ctypes.c_void_p), GL_STREAM_DRAW)
        self.gl.BindBuffer(GL_PIXEL_UNPACK_BUFFER, 0)

    def release(self) -> None:
        """Delete the OpenGL buffer (its context current)."""
        name = _u(self.name)
        self.gl.DeleteBuffers(1, ctypes.byref(name))


class TextureWriter:
    """Writes light grids into the textures of some of a VTK GPU ray caster's input ports
    (see the module docstring).

    Parameters
    ----------
    mapper : vtkOpenGLGPUVolumeRayCastMapper
        Observed (``VolumeMapperRenderStartEvent``, ``VolumeMapperRenderEndEvent``).
    images : dict
        ``port -> vtkImageData``: the image VTK uploads each port's texture from (kept up to
        date in the background after a direct write).
    fallback : callable
        ``fallback(ports)`` is called when a scheduled write cannot be made (an OpenGL or
        warp error, a texture that changed): it must put the grids of those ports on the
        host path (fill the images; VTK uploads them in the same render).
    formats : dict, optional
        ``port -> TexelFormat`` of each port's image and texture (default :data:`RGBA16`
        for every port).
    """

    def __init__(self, mapper, images: dict, fallback, formats: dict | None = None) -> None:
        from vtkmodules.vtkCommonCore import vtkCommand

        self.images = {int(port): image for port, image in images.items()}
        self.formats = {port: (formats or {}).get(port, RGBA16) for port in self.images}
        self.ports = tuple(self.images)
        self.fallback = fallback
        self.textures: dict[int, Texture] = {}   # found by their texels
        self._drawn: dict[int, int] = {}          # port -> image MTime at the last render end
        self.pending: dict[int, Job] = {}        # to write at the next render start
        self.writes = 0                          # texture writes made (tests, benchmarks)
        self.host_stale = False                  # an image missed its background copy
        self.last_error: str | None = None
        self._buffers: dict[int, PixelBuffer] = {}
        self._texels: dict[int, object] = {}     # port -> packed texels (warp, uint16)
        self._copies: list = []                  # background copies to the host images
        self._pool = None
        self._gl = None

        self._observers = [
            mapper.AddObserver(vtkCommand.VolumeMapperRenderStartEvent,
                               lambda caller, event: self._flush()),
            mapper.AddObserver(vtkCommand.VolumeMapperRenderEndEvent,
                               lambda caller, event: self._rendered()),
        ]
        self._mapper = mapper

    # --- what the mapper asks ------------------------------------------------------------------
    def can_write(self, port: int, size: tuple) -> bool:
        """Whether ``port``'s texture is (as far as is known without OpenGL) ``size``
        texels of the port's format: found so, or made from a port image of that size."""
        size = tuple(int(n) for n in size)
        tex = self.textures.get(int(port))
        if tex is not None and tex.size == size and \
                tex.internal_format == self.formats[int(port)].internal_format:
            return True
        return self._host_texels(int(port), size) is not None  # then found at the write

    def _host_texels(self, port: int, size: tuple):
        """The port image's values (a view, ``[n, components]``) if it has ``size`` and the
        port's format, and the mapper has rendered since it changed (VTK's texture holds
        it), else None."""
        from vtkmodules.util.numpy_support import vtk_to_numpy

        image, fmt = self.images[port], self.formats[port]
        array = image.GetPointData().GetScalars()
        if array is None or tuple(image.GetDimensions()) != tuple(size) or \
                array.GetDataType() != fmt.vtk_type or \
                array.GetNumberOfComponents() != fmt.components or \
                self._drawn.get(port) != image.GetMTime():
            return None
        return vtk_to_numpy(array).reshape(-1, fmt.components)

    def _rendered(self) -> None:
        """At a render's end: VTK's textures now hold the images as they are."""
        for port, image in self.images.items():
            self._drawn[port] = image.GetMTime()

    def schedule(self, port: int, job: Job) -> None:
        """Write ``job``'s texels into ``port``'s texture at the next render start."""
        self.pending[int(port)] = job

    def forget(self) -> None:
        """The host path owns the images again: drop what was scheduled, and let the
        background copies end first (they write into the images' arrays)."""
        self.pending.clear()
        self.sync_host()
        self.host_stale = False  # the host path rewrites every image

    def sync_host(self) -> None:
        """Wait until the images hold the grids last written (the background copies).
        A copy that failed sets :attr:`host_stale`: the next grids go through the host."""
        copies, self._copies = self._copies, []
        for copy in copies:
            error = copy.exception()
            if error is not None:
                self.last_error = f"copy to the host image: {type(error).__name__}: {error}"
                self.host_stale = True

    def release(self) -> None:
        """Remove the observers, end the background copies and drop the pixel buffers
        (called without a current context: their OpenGL names go with the context)."""
        for tag in self._observers:
            self._mapper.RemoveObserver(tag)
        self._observers = []
        self.sync_host()
        if self._pool is not None:
            self._pool.shutdown()
        self._buffers.clear()
        self._texels.clear()

    # --- events --------------------------------------------------------------------------------
    def _gl_calls(self) -> _GL:
        if self._gl is None:
            self._gl = _GL()
        return self._gl

    def _flush(self) -> None:
        if not self.pending:
            return
        jobs, self.pending = self.pending, {}
        failed = []
        try:
            gl = self._gl_calls()
            bound = gl.integer(GL_TEXTURE_BINDING_3D)
        except (RuntimeError, ValueError) as err:  # a VTK or OpenGL without these calls
            self.last_error = str(err)
            failed = list(jobs)
            jobs = {}
        try:
            for port, job in jobs.items():
                try:
                    texture = self._texture(gl, port, job)
                    written = texture is not None and self._write(gl, port, texture, job)
                except RuntimeError as err:  # a call this OpenGL does not offer
                    self.last_error, written = str(err), False
                if not written:
                    failed.append(port)
        finally:
            if jobs:
                gl.BindTexture(GL_TEXTURE_3D, bound)
        if failed:
            self.sync_host()
            self.fallback(failed)

    def _texture(self, gl: _GL, port: int, job: Job) -> Texture | None:
        """The port's texture as known (its label proves the name is still VTK's texture
        of the port; VTK may have given it another size since) or found anew."""
        texture = self.textures.get(port)
        if texture is not None and gl.IsTexture(texture.name) and \
                gl.label(texture.name) == texture.label and \
                self._fits(gl, texture.name, job.size, self.formats[port]):
            return texture
        self.textures.pop(port, None)
        return self._find(gl, port, tuple(job.size))

    def _fits(self, gl: _GL, name: int, size, fmt: TexelFormat) -> bool:
        """Whether texture ``name`` is ``size`` texels of ``fmt`` (level 0)."""
        found = []
        level = _i(0)
        for parameter in (GL_TEXTURE_WIDTH, GL_TEXTURE_HEIGHT, GL_TEXTURE_DEPTH,
                          GL_TEXTURE_INTERNAL_FORMAT):
            gl.GetTextureLevelParameteriv(name, 0, parameter, ctypes.byref(level))
            found.append(level.value)
        return tuple(found[:3]) == tuple(int(n) for n in size) and \
            found[3] == fmt.internal_format

    def _find(self, gl: _GL, port: int, size: tuple) -> Texture | None:
        """VTK's texture of ``port`` among all texture names: the one texture of ``size``
        and the port's format whose texels equal the port image's (bit for bit) at 24 places, asked only once the
        mapper has rendered since the image changed (VTK's own texture is then one of
        them). None when there is none or more than one."""
        self.sync_host()  # the image must hold what the texture was last given
        host = self._host_texels(port, size)
        if host is None:
            return None
        count = host.shape[0]
        rng = np.random.default_rng(port)
        places = np.unique(np.concatenate([np.linspace(0, count - 1, 12).astype(np.int64),
                                           rng.integers(0, count, 12)]))
        expected = [host[place].tobytes() for place in places]
        fmt = self.formats[port]
        probe = _u(0)
        gl.GenTextures(1, ctypes.byref(probe))  # a name above (about) every name in use
        gl.DeleteTextures(1, ctypes.byref(probe))
        width, height = size[0], size[1]
        pack = gl.integer(GL_PIXEL_PACK_BUFFER_BINDING)
        gl.BindBuffer(GL_PIXEL_PACK_BUFFER, 0)
        nbytes = fmt.components * fmt.itemsize
        texel = ctypes.create_string_buffer(nbytes)
        matches = []
        try:
            for name in range(1, max(int(probe.value), 256) + 64):
                if not gl.IsTexture(name) or not self._fits(gl, name, size, fmt):
                    continue
                same = True
                for place, values in zip(places, expected):
                    x, y, z = place % width, (place // width) % height, place // (width * height)
                    gl.GetTextureSubImage(name, 0, int(x), int(y), int(z), 1, 1, 1,
                                          fmt.gl_format, fmt.gl_type, nbytes, texel)
                    if texel.raw != values:
                        same = False
                        break
                if same:
                    matches.append(name)
        finally:
            gl.BindBuffer(GL_PIXEL_PACK_BUFFER, pack)
        gl.GetError()  # a texture without storage at level 0 answered with an error: not ours
        if len(matches) != 1:
            return None
        name = matches[0]
        label = f"vtkillum-{id(self):x}-{port}-{name}".encode()
        gl.ObjectLabel(GL_TEXTURE, name, -1, label)
        texture = Texture(name, tuple(size), fmt.internal_format, label)
        self.textures[port] = texture
        return texture

    def _write(self, gl: _GL, port: int, texture: Texture, job: Job) -> bool:
        """Pack ``job`` on its device, copy it through the port's pixel buffer into
        ``texture`` and start the copy to the host image;
        False on an OpenGL or warp error (nothing of it reached the texture)."""
        import warp as wp

        from vtkillum.core.texels import texel_shape

        while gl.GetError():  # errors of others are not ours
            pass
        fmt = self.formats[port]
        width, height, depth = (int(n) for n in job.size)
        # the texture's texel order, width fastest, as texels.texel_shape lays it out
        shape = texel_shape(job.size, fmt.components, x_fastest=True)
        self.sync_host()  # a background copy may still read the texels of the last write
        try:
            texels = self._texels.get(port)
            if texels is None or tuple(texels.shape) != shape or \
                    str(texels.device) != job.device or texels.dtype != fmt.warp_dtype():
                texels = self._texels[port] = None  # free the old texels first
                texels = self._texels[port] = wp.empty(shape, dtype=fmt.warp_dtype(),
                                                       device=job.device)
            job.pack(texels)
            nbytes = texels.size * fmt.itemsize
            buffer = self._buffers.get(port)
            if buffer is None or buffer.nbytes != nbytes or buffer.device != job.device:
                if buffer is not None:
                    buffer.release()  # the context is current: free it now, not with it
                buffer = self._buffers[port] = PixelBuffer(gl, nbytes, job.device)
            buffer.fill(texels)
        except Exception as err:  # noqa: BLE001 -- interop unavailable: the host path draws
            self.last_error = f"{type(err).__name__}: {err}"
            self._buffers.pop(port, None)
            return False
        previous = gl.integer(GL_PIXEL_UNPACK_BUFFER_BINDING)
        alignment = gl.integer(GL_UNPACK_ALIGNMENT)
        gl.BindBuffer(GL_PIXEL_UNPACK_BUFFER, buffer.name)
        gl.PixelStorei(GL_UNPACK_ALIGNMENT, 1)
        gl.BindTexture(GL_TEXTURE_3D, texture.name)  # on the active unit (restored by _flush)
        gl.TexSubImage3D(GL_TEXTURE_3D, 0, 0, 0, 0, width, height, depth, fmt.gl_format,
                         fmt.gl_type, None)
        gl.PixelStorei(GL_UNPACK_ALIGNMENT, alignment)
        gl.BindBuffer(GL_PIXEL_UNPACK_BUFFER, previous)
        error = gl.GetError()
        if error:
            self.last_error = f"OpenGL error 0x{error:04X} writing port {port}'s texture"
            return False
        self.writes += 1
        self._copy_to_host(port, texels)
        return True

    def _copy_to_host(self, port: int, texels) -> None:
        """Copy ``texels`` into the port's image array in the background, unless the image
        no longer holds a uint16 array of their size (then the host path rewrites it)."""
        from vtkmodules.util.numpy_support import vtk_to_numpy

        array = self.images[port].GetPointData().GetScalars()
        if array is None or array.GetDataType() != self.formats[port].vtk_type or \
                array.GetNumberOfValues() != texels.size:
            return
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vtkillum-texels")

        def copy(array=array, texels=texels):  # keeps the VTK array alive while it runs
            import warp as wp

            # straight into the VTK array's memory: no host temporary of the grid's size
            into = wp.array(ptr=vtk_to_numpy(array).ctypes.data, dtype=texels.dtype,
                            shape=texels.shape, device="cpu")
            with wp.ScopedDevice(texels.device):  # this thread's CUDA context
                wp.copy(into, texels)
                wp.synchronize_device(texels.device)

        self._copies.append(self._pool.submit(copy))


class DeviceUpload:
    """The ``device_upload`` switch of a volume (a mixin for
    :class:`~vtkillum.mappers.IlluminatedVolume` and
    :class:`~vtkillum.mappers.AmbientScatteringVolume`).

    The volume has ``mapper`` and ``inputs``; the inputs stage has ``writer`` (a
    :class:`TextureWriter` or None), ``writer_images()`` (``(images, formats)``: the port
    images it may write and their :class:`TexelFormat`), ``_host_fallback(ports)`` and
    ``refill_host()`` (the next update fills every writable image on the host again).
    """

    @property
    def device_upload(self) -> bool:
        """Write grids that are warp arrays straight into VTK's textures (default True).

        On: grids a computation left on its warp device, a GPU or warp's CPU device (an
        ``IlluminatedVolume``'s light grids given as warp arrays; an ``AmbientScatteringVolume``'s ``σ̃t`` and radiance cache,
        recomputed on its device) are laid out as texels on their device
        (:mod:`vtkillum.core.texels`, the host path's texels bit for bit) and copied into
        the textures VTK made for the previous ones through an OpenGL pixel buffer
        mapped into CUDA (:mod:`vtkillum.mappers.texture_upload`): no download, no host
        packing, no upload from host memory. It applies to grids of the size VTK's
        textures already have, once a frame was drawn with it on; anything else (images,
        numpy grids, another size, an OpenGL error) goes through the host as before.
        Memory: twice the texture's bytes on the grids' device for each texture written
        (the texels and the pixel buffer), besides VTK's texture. Off: every grid goes
        through the host.
        """
        return self.inputs.writer is not None

    @device_upload.setter
    def device_upload(self, value: bool) -> None:
        if not isinstance(value, (bool, np.bool_)):
            raise TypeError(f"device_upload must be True or False, got {value!r}")
        if bool(value) == self.device_upload:
            return
        inputs = self.inputs
        if value:
            images, formats = inputs.writer_images()
            inputs.writer = TextureWriter(self.mapper, images, inputs._host_fallback, formats)
        else:
            writer, inputs.writer = inputs.writer, None
            writer.release()
            inputs.refill_host()  # the images may hold older grids: fill them again
            inputs.Modified()
            self.Modified()


__all__ = ["DeviceUpload", "Job", "PixelBuffer", "R32F", "RGBA16", "RGBA32F", "TexelFormat", "Texture",
           "TextureWriter"]
