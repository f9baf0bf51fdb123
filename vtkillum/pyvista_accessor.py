"""pyvista integration: the ``grid.illum`` accessor and :func:`add_illuminated_volume`.

Importing this module registers the accessor (pyvista >= 0.48) on
``pyvista.ImageData``::

    import pyvista as pv
    import vtkillum.pyvista_accessor  # noqa: F401  (registers grid.illum)

    grid = pv.examples.download_head()            # any pv.ImageData with point scalars
    lit = grid.illum.transmittance(lights=[vtkillum.DirectionalLight((1, -1, -1))],
                                   cmap="bone", opacity="sigmoid")
    pl = pv.Plotter()
    vtkillum.pyvista_accessor.add_illuminated_volume(pl, grid, illumination=lit,
                                                     cmap="bone", opacity="sigmoid")

The methods run the filters of :mod:`vtkillum.filters` and return new
``pyvista.ImageData`` holding their arrays; each is also a plain function of this
module taking the grid first (``transmittance(grid, ...)``).

Transfer functions follow ``Plotter.add_volume``: ``cmap`` (a colormap name,
matplotlib colormap, list of colours or ``pyvista.LookupTable``), ``opacity`` (a
name such as ``'linear'``, ``'sigmoid'``, ``'geom_r'``, a float or a list of
values spread over ``clim``), ``clim`` (default: the data range), ``n_colors``
and ``flip_scalars``; the tables are built with ``pyvista.LookupTable`` exactly as
``add_volume`` builds them. ``opacity_unit_distance`` defaults to pyvista's too
(``grid.length / (mean(grid.dimensions) - 1)``), so a given ``cmap``/``opacity``
looks as dense as with ``add_volume``. Alternatively pass ``transfer_function=``
a :class:`vtkillum.TransferFunction`.

Lights are :class:`vtkillum.DirectionalLight` / :class:`vtkillum.PointLight`, or
``pyvista.Light`` objects (a directional light travels from ``position`` towards
``focal_point`` with irradiance ``intensity * color``; a positional one becomes
a point light of intensity ``intensity * color``). Default: one white directional
light travelling along (1, -1, -1).
"""

from __future__ import annotations

import numpy as np
import pyvista as pv
from vtkmodules.vtkCommonDataModel import vtkDataObject, vtkImageData

from vtkillum.core.lights import DirectionalLight, PointLight
from vtkillum.core.render import render as core_render
from vtkillum.core.scene import Scene
from vtkillum.core.tonemap import tonemap, write_png
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters.ambient_extinction import AmbientExtinctionFilter
from vtkillum.filters.convection_diffusion_light import ConvectionDiffusionLightFilter
from vtkillum.filters.light_transmittance import LightTransmittanceFilter
from vtkillum.filters.optical_properties import OpticalPropertiesFilter
from vtkillum.filters.rgba_output import DEFAULT_EXPOSURE, with_rgba_output
from vtkillum.io.convert import transfer_function_from_vtk, transfer_function_to_vtk
from vtkillum.io.convert import volume_from_image_data

#: Name of the accessor on ``pyvista.ImageData``.
ACCESSOR = "illum"

__all__ = [
    "IllumAccessor",
    "add_illuminated_volume",
    "ambient_extinction",
    "convection_diffusion",
    "lights_from_pyvista",
    "optical_properties",
    "render",
    "transfer_function_from_pyvista",
    "transmittance",
]


# === conversions ===================================================================================
def pyvista_unit_distance(grid) -> float:
    """``Plotter.add_volume``'s default opacity unit distance for ``grid``."""
    return float(grid.length / (np.mean(grid.dimensions) - 1))


def transfer_function_from_pyvista(grid, scalars=None, cmap=None, opacity="linear", clim=None,
                                   n_colors: int = 256, flip_scalars: bool = False):
    """Colour and opacity of ``add_volume``'s conventions as VTK transfer functions.

    Parameters
    ----------
    grid : pyvista.ImageData
        Gives the default ``clim`` (the range of ``scalars``).
    scalars : str, optional
        Point array; default the active scalars.
    cmap, opacity, clim, n_colors, flip_scalars
        As in ``pyvista.Plotter.add_volume``; ``cmap=None`` takes the theme's colormap.

    Returns
    -------
    (vtkColorTransferFunction, vtkPiecewiseFunction)

    Examples
    --------
    >>> import pyvista as pv
    >>> grid = pv.ImageData(dimensions=(4, 4, 4))
    >>> grid["v"] = range(64)
    >>> ctf, otf = transfer_function_from_pyvista(grid, cmap="viridis", opacity="linear")
    >>> round(otf.GetValue(0.0), 3), round(otf.GetValue(63.0), 3)
    (0.0, 0.998)
    """
    if isinstance(cmap, pv.LookupTable):
        lut = cmap
    else:
        from pyvista.plotting.colors import get_cmap_safe

        lut = pv.LookupTable()
        cmap_obj = get_cmap_safe(cmap if cmap is not None else pv.global_theme.cmap)
        if flip_scalars:
            cmap_obj = cmap_obj.reversed()
        lut.apply_cmap(cmap_obj, n_colors)
        lut.apply_opacity(opacity)
        values = _scalars(grid, scalars)
        if clim is None:
            clim = (float(np.nanmin(values)), float(np.nanmax(values)))
        elif isinstance(clim, (int, float)):
            clim = (-float(clim), float(clim))
        if clim[1] <= clim[0]:
            clim = (clim[0], clim[0] + 1.0)
        lut.scalar_range = clim
    return lut.to_color_tf(), lut.to_opacity_tf()


def lights_from_pyvista(lights) -> list:
    """Core lights from core lights, ``pyvista.Light`` objects (or one of either), or None.

    Examples
    --------
    >>> import pyvista as pv
    >>> light = pv.Light(position=(0, 0, 5), focal_point=(0, 0, 0), intensity=2.0)
    >>> lights_from_pyvista(light)[0].direction.tolist()
    [0.0, 0.0, -1.0]
    """
    if lights is None:
        return [DirectionalLight((1.0, -1.0, -1.0))]
    if isinstance(lights, (DirectionalLight, PointLight, pv.Light)):
        lights = [lights]
    out = []
    for light in lights:
        if isinstance(light, (DirectionalLight, PointLight)):
            out.append(light)
        elif isinstance(light, pv.Light):
            rgb = np.asarray(light.diffuse_color.float_rgb) * float(light.intensity)
            if light.positional:
                out.append(PointLight(light.position, rgb))
            else:
                travel = np.subtract(light.focal_point, light.position)
                out.append(DirectionalLight(travel, rgb))
        else:
            raise TypeError(f"lights must be vtkillum DirectionalLight/PointLight or pyvista.Light "
                            f"objects, got {type(light).__name__}")
    if not out:
        raise ValueError("lights: give at least one light (or None for the default light)")
    return out


def _scalars(grid, scalars):
    if scalars is None:
        values = grid.active_scalars
        if values is None:
            raise ValueError(f"the grid has no active scalars; pass scalars=<name> (point arrays: "
                             f"{list(grid.point_data.keys())})")
        return values
    if scalars not in grid.point_data:
        raise ValueError(f"the grid has no point array {scalars!r} (point arrays: "
                         f"{list(grid.point_data.keys())})")
    return grid.point_data[scalars]


def _check_grid(grid) -> None:
    if not isinstance(grid, vtkImageData):
        raise TypeError(f"expected a pyvista.ImageData (uniform grid), got {type(grid).__name__}; "
                        "resample other meshes first, e.g. pv.ImageData(...).sample(mesh)")


def _optics(grid, scalars, cmap, opacity, clim, n_colors, flip_scalars, transfer_function,
            opacity_unit_distance):
    """(vtk colour TF, vtk opacity TF, unit distance) from either convention."""
    _check_grid(grid)
    if transfer_function is not None:
        if cmap is not None or clim is not None or not (isinstance(opacity, str)
                                                        and opacity == "linear"):
            raise ValueError("give either transfer_function=... or cmap/opacity/clim, not both")
        if not isinstance(transfer_function, TransferFunction):
            raise TypeError("transfer_function must be a vtkillum.TransferFunction")
        ctf, otf = transfer_function_to_vtk(transfer_function)
    else:
        ctf, otf = transfer_function_from_pyvista(grid, scalars, cmap, opacity, clim, n_colors,
                                                  flip_scalars)
    u = pyvista_unit_distance(grid) if opacity_unit_distance is None else float(opacity_unit_distance)
    return ctf, otf, u


def _run(filter_class, grid, scalars, optics, settings: dict, lights=None, rgba=False,
         exposure=DEFAULT_EXPOSURE):
    """Configure a filter, run it on ``grid`` and return its output as new pyvista.ImageData."""
    _check_grid(grid)
    _scalars(grid, scalars)
    cls = with_rgba_output(filter_class) if rgba else filter_class
    algorithm = cls()
    ctf, otf, u = optics
    algorithm.SetColorTransferFunction(ctf)
    algorithm.SetScalarOpacity(otf)
    algorithm.SetScalarOpacityUnitDistance(u)
    if lights is not None:
        algorithm.SetLights(lights_from_pyvista(lights))
    if rgba:
        algorithm.SetExposure(exposure)
    if scalars is not None:
        algorithm.SetInputArrayToProcess(0, 0, 0, vtkDataObject.FIELD_ASSOCIATION_POINTS, scalars)
    for key, value in settings.items():
        if value is None:
            continue
        setter = getattr(algorithm, f"Set{key}")
        setter(*value) if isinstance(value, tuple) else setter(value)
    output = algorithm.execute(grid)
    result = pv.ImageData()
    result.shallow_copy(output)
    return result


# === the filters as functions ======================================================================
def optical_properties(grid, scalars=None, *, cmap=None, opacity="linear", clim=None,
                       n_colors=256, flip_scalars=False, transfer_function=None,
                       opacity_unit_distance=None, albedo=0.9, output_scale=1.0):
    """Extinction and scattering coefficients per point (:class:`OpticalPropertiesFilter`).

    Returns
    -------
    pyvista.ImageData
        ``sigma_t`` (active), ``scattering_color``, ``sigma_s``, ``sigma_a`` and the
        input arrays.

    Examples
    --------
    >>> import pyvista as pv, vtkillum, vtkillum.pyvista_accessor
    >>> grid = pv.ImageData(dimensions=(8, 8, 8))
    >>> grid["density"] = [1.0] * grid.n_points
    >>> tf = vtkillum.TransferFunction([0.0, 1.0], [0.5, 0.5])
    >>> out = grid.illum.optical_properties(transfer_function=tf, opacity_unit_distance=1.0)
    >>> round(float(out["sigma_t"].max()), 4)       # -ln(1 - 0.5) / 1
    0.6931

    pyvista's opacity tables hold 8-bit values: ``opacity=0.5`` is 127/255.

    >>> out = grid.illum.optical_properties(opacity=0.5, opacity_unit_distance=1.0)
    >>> round(float(out["sigma_t"].max()), 4)       # -ln(1 - 127/255)
    0.6892
    """
    optics = _optics(grid, scalars, cmap, opacity, clim, n_colors, flip_scalars,
                     transfer_function, opacity_unit_distance)
    return _run(OpticalPropertiesFilter, grid, scalars, optics,
                {"Albedo": albedo, "OutputScale": output_scale})


def transmittance(grid, lights=None, scalars=None, *, cmap=None, opacity="linear", clim=None,
                  n_colors=256, flip_scalars=False, transfer_function=None,
                  opacity_unit_distance=None, albedo=0.9, light_volume_scale=1.0,
                  step_size=None, device=None, rgba=False, exposure=DEFAULT_EXPOSURE):
    """Shadow rays towards every light (:class:`LightTransmittanceFilter`).

    Parameters
    ----------
    lights : light or list of lights, optional
        See the module docstring.
    light_volume_scale : float
        Resolution of the light grid relative to the data, in (0, 1].
    step_size : float, optional
        Longest step along shadow rays (world units); default half the smallest spacing.
    device : str, optional
        ``"cpu"``, ``"cuda"``; default CUDA when present.
    rgba : bool
        Also output ``illuminated_rgba`` (:mod:`vtkillum.filters.rgba_output`) with ``exposure``.

    Returns
    -------
    pyvista.ImageData
        ``fluence`` (RGB, active), ``transmittance`` (one component per light),
        ``scattered_fluence`` (zeros), and at full resolution the input arrays
        (:mod:`vtkillum.io.illumination_arrays`).

    Examples
    --------
    A slab of extinction 1 per unit lit from +z: the transmittance at the bottom is
    ``exp(-height)``.

    >>> import numpy as np, pyvista as pv, vtkillum, vtkillum.pyvista_accessor
    >>> grid = pv.ImageData(dimensions=(6, 6, 11), spacing=(0.1, 0.1, 0.1))
    >>> grid["density"] = np.ones(grid.n_points)
    >>> tf = vtkillum.TransferFunction([0.0, 1.0], [1 - np.exp(-1.0)] * 2)
    >>> out = grid.illum.transmittance(vtkillum.DirectionalLight((0, 0, -1)),
    ...                                transfer_function=tf, opacity_unit_distance=1.0,
    ...                                device="cpu")
    >>> t = out["transmittance"].reshape(11, 6, 6)         # [k, j, i], one light
    >>> round(float(t[0, 3, 3]), 3), round(float(np.exp(-1.0)), 3)
    (0.368, 0.368)
    """
    optics = _optics(grid, scalars, cmap, opacity, clim, n_colors, flip_scalars,
                     transfer_function, opacity_unit_distance)
    return _run(LightTransmittanceFilter, grid, scalars, optics,
                {"Albedo": albedo, "OutputScale": light_volume_scale, "StepSize": step_size,
                 "Device": device}, lights=lights, rgba=rgba, exposure=exposure)


def convection_diffusion(grid, lights=None, scalars=None, *, cmap=None, opacity="linear",
                         clim=None, n_colors=256, flip_scalars=False, transfer_function=None,
                         opacity_unit_distance=None, albedo=0.9, scattering=(0.0, 0.0, 0.0),
                         light_volume_scale=0.5, iterations=0, tolerance=1e-4,
                         solver="multigrid", device=None, rgba=False,
                         exposure=DEFAULT_EXPOSURE, diffusion_model="physical", anisotropy=0.0):
    """Zhang & Ma's convection–diffusion light volume (:class:`ConvectionDiffusionLightFilter`).

    ``diffusion_model`` is ``"physical"`` (default: radiative-transfer diffusion from
    ``albedo``, ``anisotropy`` and the transfer functions) or ``"paper"`` (Zhang & Ma's
    diffusion with ``scattering``, the coefficient per RGB channel in world units², one
    number for all channels); other parameters as in :func:`transmittance`.

    Returns
    -------
    pyvista.ImageData
        ``fluence`` (active), ``transmittance`` (physical model), ``scattered_fluence`` on
        the light grid (or, with ``rgba=True``, on the data grid with ``illuminated_rgba``).
    """
    if np.ndim(scattering) == 0:
        scattering = (float(scattering),) * 3
    optics = _optics(grid, scalars, cmap, opacity, clim, n_colors, flip_scalars,
                     transfer_function, opacity_unit_distance)
    return _run(ConvectionDiffusionLightFilter, grid, scalars, optics,
                {"Albedo": albedo, "Anisotropy": anisotropy, "LightVolumeScale": light_volume_scale,
                 "DiffusionModel": diffusion_model,
                 "Scattering": tuple(float(s) for s in scattering), "Iterations": iterations,
                 "Tolerance": tolerance, "Solver": solver, "Device": device},
                lights=lights, rgba=rgba, exposure=exposure)


def ambient_extinction(grid, lights=None, scalars=None, *, cmap=None, opacity="linear",
                       clim=None, n_colors=256, flip_scalars=False, transfer_function=None,
                       opacity_unit_distance=None, albedo=0.9, anisotropy=0.0, radius=4.0,
                       radius_units="voxels", compute_radiance=True, output_scale=1.0,
                       device=None):
    """Ament et al.'s ambient extinction and radiance cache (:class:`AmbientExtinctionFilter`).

    Returns
    -------
    pyvista.ImageData
        ``ambient_extinction`` (active), ``ambient_radiance`` and
        ``ambient_radiance_<l>`` per light.
    """
    optics = _optics(grid, scalars, cmap, opacity, clim, n_colors, flip_scalars,
                     transfer_function, opacity_unit_distance)
    return _run(AmbientExtinctionFilter, grid, scalars, optics,
                {"Albedo": albedo, "Anisotropy": anisotropy, "Radius": radius,
                 "RadiusUnits": radius_units, "ComputeRadiance": compute_radiance,
                 "OutputScale": output_scale, "Device": device}, lights=lights)


def render(grid, method="single", scalars=None, *, lights=None, cmap=None, opacity="linear",
           clim=None, n_colors=256, flip_scalars=False, transfer_function=None,
           opacity_unit_distance=None, albedo=0.9, anisotropy=0.0, camera=None, width=256,
           height=256, background=(0.0, 0.0, 0.0), device=None, filename=None,
           exposure=1.0, gamma=2.2, **options):
    """Render ``grid`` with a registered method of :data:`vtkillum.METHODS`.

    Parameters
    ----------
    method : str
        ``"emission"``, ``"single"``, ``"illumination"`` (give ``illumination=`` an
        output of :func:`transmittance` / :func:`convection_diffusion`, or an
        ``IlluminationVolume``), ``"path"``, ...
    camera : vtkillum.Camera or pyvista.Camera, optional
        Default: framing the volume like ``vtkRenderer.ResetCamera``.
    filename : str, optional
        Also write ``tonemap(exposure * radiance, alpha, background, gamma)`` as PNG.
    **options
        Method options (``spp`` for ``path``, ``illumination`` for ``illumination``...).

    Returns
    -------
    vtkillum.RenderResult
        Linear ``radiance`` (H, W, 3), ``alpha`` (H, W) and ``info``.

    Examples
    --------
    >>> import numpy as np, pyvista as pv, vtkillum.pyvista_accessor
    >>> grid = pv.ImageData(dimensions=(9, 9, 9), spacing=(0.25, 0.25, 0.25))
    >>> grid["density"] = np.ones(grid.n_points)
    >>> result = grid.illum.render("emission", opacity=0.5, width=24, height=24, device="cpu")
    >>> result.radiance.shape, bool(result.alpha.max() > 0.5)
    ((24, 24, 3), True)
    """
    _check_grid(grid)
    ctf, otf, u = _optics(grid, scalars, cmap, opacity, clim, n_colors, flip_scalars,
                          transfer_function, opacity_unit_distance)
    volume = volume_from_image_data(grid, scalars, association="points")
    illumination = options.get("illumination")
    if isinstance(illumination, vtkImageData):
        from vtkillum.io.illumination_arrays import illumination_from_image

        options["illumination"] = illumination_from_image(illumination, volume)
    if camera is not None and isinstance(camera, pv.Camera):
        from vtkillum.mappers.camera_bridge import camera_from_vtk

        camera = camera_from_vtk(camera, aspect=width / height)
    scene = Scene(transfer_function=transfer_function_from_vtk(ctf, otf),
                  opacity_unit_distance=u, albedo=albedo, anisotropy=anisotropy,
                  lights=lights_from_pyvista(lights), camera=camera, background=background)
    result = core_render(volume, scene, method, width, height, device=device, **options)
    if filename is not None:
        write_png(filename, tonemap(exposure * result.radiance, result.alpha, background,
                                    exposure=1.0, gamma=gamma))
    return result


# === plotting =========================================================================================
def add_illuminated_volume(plotter, grid, illumination=None, scalars=None, *, cmap=None,
                           opacity="linear", clim=None, n_colors=256, flip_scalars=False,
                           transfer_function=None, opacity_unit_distance=None, lights=None,
                           albedo=0.9, exposure=4 * np.pi, shading=None, step_size=None, name=None,
                           reset_camera=None, render=True):
    """Add ``grid`` shaded by an illumination volume to a pyvista plotter.

    Builds an :class:`~vtkillum.mappers.IlluminatedVolume` (VTK's GPU ray caster
    with the illumination-volume source term) and adds it with
    ``plotter.add_actor``; ``cmap``, ``opacity``, ``clim`` follow
    ``Plotter.add_volume``.

    Parameters
    ----------
    plotter : pyvista.Plotter
    grid : pyvista.ImageData
        Point scalars (``scalars``, default the active ones).
    illumination : optional
        The fluence: the output of :func:`transmittance` / :func:`convection_diffusion`
        (any pyvista/VTK image with a ``fluence`` array covering the grid's box), a
        VTK algorithm or output port producing one, an ``IlluminationVolume`` or
        ``(nx, ny, nz, 3)`` array, the name of a method (``"transmittance"`` or
        ``"convection_diffusion"``, computed here with these lights and transfer
        function), or ``None`` for unshadowed light.
    lights : optional
        As in :func:`transmittance`; also used for shading directions.
    albedo, exposure : float
        Scattering albedo; factor on the radiance written to the frame buffer. The
        default 4π shows a fully lit voxel under irradiance 1 as albedo × colour (the
        isotropic phase function spreads scattered light over 4π sr), as the ParaView
        plugin does.
    shading : dict, optional
        ``{"ambient", "diffuse", "specular", "shininess"}`` of the illumination
        shading (default ambient 1: pure scattering).
    step_size : float, optional
        Sample distance of the ray caster; default half the smallest spacing.
    name, reset_camera, render
        As in ``Plotter.add_actor``.

    Returns
    -------
    vtkillum.mappers.IlluminatedVolume
        The actor (a ``vtkVolume``).

    Examples
    --------
    >>> import numpy as np, pyvista as pv, vtkillum
    >>> from vtkillum.pyvista_accessor import add_illuminated_volume
    >>> grid = pv.ImageData(dimensions=(12, 12, 12), spacing=(0.2, 0.2, 0.2))
    >>> grid["density"] = np.linspace(0.0, 1.0, grid.n_points)
    >>> pl = pv.Plotter(off_screen=True, window_size=(64, 64))
    >>> actor = add_illuminated_volume(pl, grid, illumination="transmittance",
    ...                                cmap="bone", opacity="linear", exposure=8.0)
    >>> image = pl.screenshot()
    >>> image.shape, bool(image.max() > 0)
    ((64, 64, 3), True)
    >>> pl.close()
    """
    from vtkillum.core.scene import SHADING_DEFAULTS
    from vtkillum.mappers.illuminated_volume_mapper import IlluminatedVolume

    _check_grid(grid)
    ctf, otf, u = _optics(grid, scalars, cmap, opacity, clim, n_colors, flip_scalars,
                          transfer_function, opacity_unit_distance)
    core_lights = lights_from_pyvista(lights)
    if isinstance(illumination, str):
        methods = {"transmittance": transmittance, "convection_diffusion": convection_diffusion}
        if illumination not in methods:
            raise ValueError(f"illumination={illumination!r}: name one of {sorted(methods)}, or "
                             "pass a filter output")
        tf = transfer_function_from_vtk(ctf, otf)
        illumination = methods[illumination](grid, core_lights, scalars, transfer_function=tf,
                                             opacity_unit_distance=u, albedo=albedo)
    scene = Scene(transfer_function=transfer_function_from_vtk(ctf, otf),
                  opacity_unit_distance=u, albedo=albedo, lights=core_lights,
                  step_size=step_size, shading=dict(SHADING_DEFAULTS, **(shading or {})))
    volume = IlluminatedVolume(grid, scene, illumination=illumination, array_name=scalars,
                               exposure=exposure)
    plotter.add_actor(volume, name=name, reset_camera=reset_camera, render=render)
    return volume


# === the accessor ======================================================================================
class IllumAccessor:
    """``grid.illum``: the vtkillum filters and renderers on a ``pyvista.ImageData``.

    Each method is the module function of the same name with the grid first.
    """

    def __init__(self, grid) -> None:
        self._grid = grid

    def optical_properties(self, *args, **kwargs):
        return optical_properties(self._grid, *args, **kwargs)

    def transmittance(self, *args, **kwargs):
        return transmittance(self._grid, *args, **kwargs)

    def convection_diffusion(self, *args, **kwargs):
        return convection_diffusion(self._grid, *args, **kwargs)

    def ambient_extinction(self, *args, **kwargs):
        return ambient_extinction(self._grid, *args, **kwargs)

    def render(self, *args, **kwargs):
        return render(self._grid, *args, **kwargs)

    def add_to(self, plotter, *args, **kwargs):
        """:func:`add_illuminated_volume` of this grid."""
        return add_illuminated_volume(plotter, self._grid, *args, **kwargs)


for _method in ("optical_properties", "transmittance", "convection_diffusion",
                "ambient_extinction", "render"):
    getattr(IllumAccessor, _method).__doc__ = globals()[_method].__doc__


def register() -> None:
    """Register ``grid.illum`` on ``pyvista.ImageData`` once (importing this module does it).

    With pyvista < 0.48 (no accessors) this warns and the module functions still work.
    """
    if not hasattr(pv, "register_dataset_accessor"):
        import warnings

        warnings.warn(f"pyvista {pv.__version__} has no dataset accessors (>= 0.48 needed): "
                      "use the functions of vtkillum.pyvista_accessor instead of grid.illum",
                      stacklevel=2)
        return
    if ACCESSOR not in vars(pv.ImageData):
        pv.register_dataset_accessor(ACCESSOR, pv.ImageData)(IllumAccessor)


register()
