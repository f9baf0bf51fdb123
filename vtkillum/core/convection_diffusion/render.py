"""The ``"convection-diffusion"`` render method: update the light volume, then ray cast with it."""

from __future__ import annotations

from vtkillum.core.convection_diffusion.solver import OPTIONS, ConvectionDiffusionSolver

#: Share of the progress bar for the light volume (the rest is the ray casting).
LIGHT_PROGRESS_SHARE = 0.3


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
        ``progress(fraction)``: the light volume's stages and diffusion iterations up to
        :data:`LIGHT_PROGRESS_SHARE`, then the ray caster's tiles.
    light_volume_scale : float
        Light-volume resolution relative to the data's (0.5: half).
    diffusion_model : str
        ``"physical"`` (default; diffusion approximation of radiative transfer from the
        scene's optical model: ``sigma_t``, albedo, colours, anisotropy) or ``"paper"``
        (Zhang & Ma's eq. 23 with ``scattering``); see
        :mod:`~vtkillum.core.convection_diffusion.solver`.
    scattering : (3,) float
        ``"paper"`` only: diffusion coefficient ``sigma_hat_s`` per RGB channel, world
        units² (the square of the diffusion length); 0 disables diffusion.
    iterations : int
        Diffusion iteration budget; 0 iterates until ``tolerance``.
    solver : str
        ``"multigrid"``, ``"gauss-seidel"``, and for the paper model ``"cg"`` or ``"dct"``.
    tolerance : float
        Relative residual at which the diffusion stops.
    source_radius : float
        Point lights' source region (world units); 0: two light-grid spacings (eq. 15).
    convection_scheme : str
        ``"characteristics"`` (default), ``"exponential"`` or ``"upwind"`` (the paper's
        eqs. 16–20); not a scene field.
    flux_limiter : str
        Physical model: ``"levermore-pomraning"`` (default), ``"wilson"``, ``"larsen"`` or
        ``"none"``; not a scene field.
    delta_scaling : bool
        Physical model: δ-Eddington scaling of the first-scattered source (default True,
        :class:`~vtkillum.core.convection_diffusion.solver.ConvectionDiffusionSolver`);
        not a scene field.
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
    config = {k: cd.get(k, v) for k, v in OPTIONS.items()}
    config["convection_scheme"] = options.pop("convection_scheme", "characteristics")
    config["flux_limiter"] = options.pop("flux_limiter", "levermore-pomraning")
    config["first_moment"] = options.pop("first_moment", True)
    config["delta_scaling"] = options.pop("delta_scaling", True)
    # One solver per volume and device, kept with the volume: a new camera (an interactive
    # window re-rendering) recomputes nothing, an edit (of the scene or of these options)
    # only what Algorithm 1 says.
    solver = volume.derived("convection_diffusion_solver", device,
                            lambda: ConvectionDiffusionSolver(device=device))
    for name, value in config.items():
        setattr(solver, name, value)
    part = LIGHT_PROGRESS_SHARE

    def light_progress(fraction):
        if progress is not None:
            progress(part * fraction)

    def render_progress(fraction):
        if progress is not None:
            progress(part + (1.0 - part) * fraction)

    stats = solver.update(volume, scene.resolved_transfer_function(volume),
                          scene.resolved_unit_distance(volume), scene.lights,
                          volume_key=volume.content_key, albedo=scene.albedo,
                          anisotropy=scene.anisotropy, progress=light_progress)
    result = render_illuminated(volume, scene, width, height, device, render_progress,
                                illumination=solver.illumination_volume(volume), **options)
    result.info["convection_diffusion"] = stats.as_dict()
    return result
