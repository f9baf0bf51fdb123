"""The ``"convection-diffusion"`` render method: update the light volume, then ray cast with it."""

from __future__ import annotations

from vtkillum.core.convection_diffusion.solver import OPTIONS, ConvectionDiffusionSolver


def render_convection_diffusion(volume, scene, width, height, device=None, progress=None,
                                **options):
    """Render with a convection–diffusion light volume (registered as ``"convection-diffusion"``).

    Parameters
    ----------
    volume : vtkillum.core.volume.Volume
    scene : vtkillum.core.scene.Scene
        Transfer function, unit distance, lights, camera, ``shading`` (eq. 24), albedo,
        and the ``convection_diffusion`` section (defaults of the options below).
    width, height : int
        Image size in pixels.
    device : str, optional
        Warp device.
    progress : callable, optional
        ``progress(fraction)`` from the ray caster.
    light_volume_scale : float
        Light-volume resolution relative to the data's (0.5: half).
    scattering : (3,) float
        Diffusion coefficient ``sigma_hat_s`` per RGB channel, world units² (the square of
        the diffusion length); 0 disables diffusion.
    iterations : int
        Diffusion iteration budget; 0 iterates until ``tolerance``.
    solver : str
        ``"multigrid"``, ``"cg"``, ``"gauss-seidel"`` or ``"dct"``.
    tolerance : float
        Relative residual at which the diffusion stops.
    source_radius : float
        Point lights' source region (world units); 0: two light-grid spacings (eq. 15).
    convection_scheme : str
        ``"characteristics"`` (default), ``"exponential"`` or ``"upwind"`` (the paper's
        eqs. 16–20); not a scene field.
    **options
        Ray-casting options of :func:`vtkillum.core.raycast.render_illuminated`
        (``step_size``, ``jitter``, ``seed``, ``early_termination``).

    Returns
    -------
    vtkillum.core.render.RenderResult
        ``info["convection_diffusion"]`` holds :meth:`UpdateStats.as_dict`.
    """
    from vtkillum.core.raycast import render_illuminated

    cd = dict(scene.options.get("convection_diffusion", {}))
    for key in OPTIONS:
        if key in options:
            cd[key] = options.pop(key)
    scheme = options.pop("convection_scheme", "characteristics")
    config = {k: cd.get(k, v) for k, v in OPTIONS.items()}
    # One solver per volume and configuration, kept with the volume: a new camera (an
    # interactive window re-rendering) recomputes nothing, an edit only what Algorithm 1 says.
    solver = volume.derived(
        "convection_diffusion_solver", (device, scheme, repr(sorted(config.items()))),
        lambda: ConvectionDiffusionSolver(device=device, convection_scheme=scheme, **config))
    stats = solver.update(volume, scene.resolved_transfer_function(volume),
                          scene.resolved_unit_distance(volume), scene.lights,
                          volume_key=volume.content_key)
    result = render_illuminated(volume, scene, width, height, device, progress,
                                illumination=solver.illumination_volume(volume), **options)
    result.info["convection_diffusion"] = stats.as_dict()
    return result
