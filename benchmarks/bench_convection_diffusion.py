"""Convection–diffusion light volumes (Zhang & Ma 2013): milliseconds per stage and solver convergence.

Prints markdown tables, for both diffusion models (``physical``, the default:
flux-limited radiative-transfer diffusion; ``paper``: Zhang & Ma's eq. 23):

1. **Stages** at the data / light-volume sizes and light counts of the paper's
   Table 1: ms for the opacity volume, the convection of one light (mean over the
   lights), the composition, the diffusion (multigrid from the previous solution, the
   default, and from a cold start; iterations), the whole light simulation after a
   transfer-function edit beside the paper's, and a 512² render
   (ray-casting kernel only) that uses the light volume. One table per model.
2. **Light-volume sizes** of the paper's Table 2: absorption (one light) and
   scattering (diffusion of each model, cold start) ms.
3. **Residual vs iterations** of every diffusion solver on one light volume (the
   physical model's residual is the nonlinear one, over the medium).
4. **One sweep vs the paper's iteration** (eq. 16 time steps to the steady state).
5. **Time series**: diffusion iterations with and without warm start.
6. **V-cycle**: one multigrid cycle of each model against the memory traffic it needs,
   at the measured copy bandwidth.
7. **Tolerance**: outer iterations, diffusion ms and the change of the light volume and
   the image when the physical diffusion stops at a looser relative residual.

Data are synthetic (an analytic cellular field, no download) at the paper's sizes;
lights alternate between oblique directional lights and point lights inside the
volume. ``sigma_hat_s`` (paper model) gives a diffusion length of 2 light-volume
spacings; the physical model uses albedo 0.9, g 0.3. Needs only numpy, warp and
vtkillum.

Examples
--------
python benchmarks/bench_convection_diffusion.py --device cuda
python benchmarks/bench_convection_diffusion.py --device cpu --sizes 32 64 --light-sizes 16 32 \\
    --solver-size 32 --iterated-size 24 --series-size 24 --render-size 128 --repeats 2
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp

from vtkillum.core.convection_diffusion import ConvectionDiffusionSolver
from vtkillum.core.convection_diffusion.convection import convect_light, convect_light_iterated
from vtkillum.core.convection_diffusion.diffusion import SOLVERS, DiffusionSolver
from vtkillum.core.convection_diffusion.radiative import RadiativeDiffusion
from vtkillum.core.device import resolve_device
from vtkillum.core.lights import DIRECTIONAL, DirectionalLight, PointLight
from vtkillum.core.scene import Scene
from vtkillum.core.transfer_function import TransferFunction
from vtkillum.core.volume import Volume

#: Zhang & Ma 2013, Table 1: name, data size, light-volume size, number of lights.
PAPER_TABLE_1 = [
    ("Parts", (504, 504, 225), (126, 126, 57), 4),
    ("Vortex (teaser)", (256, 256, 256), (128, 128, 128), 5),
    ("Machine Room", (417, 345, 60), (209, 173, 30), 4),
    ("Teapot", (256, 256, 178), (128, 128, 89), 2),
    ("Pillars", (100, 100, 100), (50, 50, 50), 4),
    ("Buckyball", (64, 64, 64), (32, 32, 32), 2),
    ("Vortex", (128, 128, 128), (128, 128, 128), 3),
    ("Smoke", (300, 300, 150), (150, 150, 75), 2),
    ("Bonsai", (256, 256, 256), (128, 128, 128), 1),
    ("Blood Vessels", (256, 256, 256), (128, 128, 128), 1),
    ("Foot", (128, 128, 128), (64, 64, 64), 1),
]
#: Zhang & Ma 2013, Table 1: light simulation (ms) on a GeForce GTX 460M.
PAPER_LIGHT_MS = {"Parts": 83, "Vortex (teaser)": 91, "Machine Room": 86, "Teapot": 54,
                  "Pillars": 49, "Buckyball": 22, "Vortex": 79, "Smoke": 54, "Bonsai": 54,
                  "Blood Vessels": 52, "Foot": 23}

TF_A = TransferFunction([0.0, 0.45, 1.0], [0.0, 0.0, 0.6], [[1, 1, 1], [1, 0.9, 0.7], [1, 1, 1]])
TF_B = TransferFunction([0.0, 0.5, 1.0], [0.0, 0.0, 0.7], [[1, 1, 1], [0.8, 0.9, 1.0], [1, 1, 1]])


def device_name(device: str) -> str:
    d = wp.get_device(device)
    return d.name if d.is_cuda else f"cpu ({d.name})"


def synthetic(dims, phase: float = 0.0) -> Volume:
    """Cellular test field in [0, 1] on a box of longest side 2 (float32, broadcast-built)."""
    dims = tuple(int(n) for n in dims)
    h = 2.0 / (max(dims) - 1)
    axes = [np.linspace(0.0, 1.0, n, dtype=np.float32) * (n - 1) * h for n in dims]
    a = np.sin(2.6 * np.pi * axes[0] + phase)[:, None, None]
    b = np.sin(2.2 * np.pi * axes[1] + 0.5 * phase)[None, :, None]
    c = np.cos(1.8 * np.pi * axes[2])[None, None, :]
    s = 0.5 + 0.5 * a * b * c
    return Volume(s.astype(np.float32), spacing=(h, h, h))


def make_lights(volume: Volume, count: int):
    """Alternating oblique directional lights and point lights inside the volume."""
    lights = []
    centre = volume.origin + 0.5 * volume.extent
    for k in range(count):
        angle = 2.0 * np.pi * k / max(count, 1)
        rgb = np.array([1.0, 0.8 + 0.2 * np.cos(angle), 0.6 + 0.4 * np.sin(angle)])
        if k % 2 == 0:
            lights.append(DirectionalLight((np.cos(angle), -0.7, np.sin(angle) + 0.3), rgb))
        else:
            offset = 0.2 * volume.extent * np.array([np.cos(angle), np.sin(angle), 0.5])
            lights.append(PointLight(centre + offset, rgb * float(np.mean(volume.extent)) ** 2))
    return lights


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000.0 * float(np.median(times))


#: Optical model of the physical diffusion in the benchmark.
ALBEDO, ANISOTROPY = 0.9, 0.3


def row_solver(dims, light_dims, count, device, **options):
    """The synthetic volume of a Table-1 row, its lights and a solver for its light volume
    (scattering length two light-grid spacings; ``options`` go to the solver)."""
    vol = synthetic(dims)
    lights = make_lights(vol, count)
    h = vol.extent / (np.asarray(light_dims) - 1)
    scattering = (2.0 * h.max()) ** 2
    cd = ConvectionDiffusionSolver(light_volume_shape=light_dims, scattering=[scattering] * 3,
                                   device=device, **options)
    return vol, lights, cd


def stage_table(rows, device, repeats, render_size, model, tolerance: float = 1e-4) -> None:
    from vtkillum.core.raycast import render_illuminated

    name = device_name(device)
    print(f"\n### 1. Stages (ms), {model} model, device {name}: short characteristics, "
          f"multigrid diffusion to a relative residual of {tolerance:g} after a "
          "transfer-function edit, from the previous solution (warm, the default) and from a "
          "cold start; paper: GTX 460M\n")
    print("| data | data size | light volume | lights | start | opacity | convection / light | "
          "composition | diffusion (iters) | light simulation | paper | speed-up | render "
          f"{render_size}² |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (label, dims, light_dims, count), warm in (
            (row, warm) for row in rows for warm in (True, False)):
        vol, lights, cd = row_solver(dims, light_dims, count, device, diffusion_model=model,
                                     warm_start=warm, tolerance=tolerance)
        for tf in (TF_A, TF_B, TF_A):  # upload, allocate, record the launch graphs
            cd.update(vol, tf, vol.mean_spacing(), lights, volume_key=label, albedo=ALBEDO,
                      anisotropy=ANISOTROPY)
        samples = []
        for r in range(repeats):  # transfer-function edits: every stage runs
            tf = TF_B if r % 2 == 0 else TF_A
            t0 = time.perf_counter()
            stats = cd.update(vol, tf, vol.mean_spacing(), lights, volume_key=label,
                              albedo=ALBEDO, anisotropy=ANISOTROPY)
            wp.synchronize_device(device)
            total = 1000.0 * (time.perf_counter() - t0)
            samples.append((stats.ms["opacity"], float(np.mean(stats.ms["convection"])),
                            stats.ms["composition"], stats.ms["diffusion"], total,
                            stats.diffusion.iterations))
        med = np.median(np.array(samples), axis=0)
        scene = Scene(transfer_function=TF_A, lights=lights, albedo=ALBEDO, anisotropy=ANISOTROPY)
        ilv = cd.illumination_volume(vol)
        render_illuminated(vol, scene, render_size, render_size, device, illumination=ilv)
        render_ms = np.median([1000.0 * render_illuminated(
            vol, scene, render_size, render_size, device, illumination=ilv).info["render_s"]
            for _ in range(max(1, repeats // 2))])
        paper = PAPER_LIGHT_MS.get(label)
        versus = f"{paper} | {paper / med[4]:.1f}×" if paper else "— | —"
        print(f"| {label} | {'x'.join(map(str, dims))} | {'x'.join(map(str, light_dims))} | "
              f"{count} | {'warm' if warm else 'cold'} | {med[0]:.2f} | {med[1]:.2f} | "
              f"{med[2]:.2f} | {med[3]:.2f} ({med[5]:.0f}) | {med[4]:.2f} | {versus} | "
              f"{render_ms:.2f} |")


def tolerance_table(rows, device, tolerances, render_size) -> None:
    """Outer iterations, warm diffusion ms and the change of the light and the image when the
    physical diffusion stops at each of ``tolerances`` instead of the first."""
    from vtkillum.core.raycast import render_illuminated

    print(f"\n### 7. Diffusion tolerance, physical model, device {device_name(device)}: three "
          "transfer-function edits after the first solve, warm; differences against "
          f"tolerance {tolerances[0]:g} (scattered fluence: largest over the edits, of its "
          f"maximum; {render_size}² image of the last edit: mean, of its mean)\n")
    print("| data | light volume | lights | tolerance | outer iterations | diffusion ms (median) "
          "| scattered fluence max diff. | image mean diff. |")
    print("|---|---|---|---|---|---|---|---|")
    for label, dims, light_dims, count in rows:
        reference = None
        for tol in tolerances:
            vol, lights, cd = row_solver(dims, light_dims, count, device,
                                         diffusion_model="physical", tolerance=tol)
            iterations, ms, fluences = [], [], []
            for r in range(4):
                tf = TF_A if r % 2 == 0 else TF_B
                stats = cd.update(vol, tf, vol.mean_spacing(), lights, volume_key=label,
                                  albedo=ALBEDO, anisotropy=ANISOTROPY)
                if r:
                    iterations.append(stats.diffusion.iterations)
                    ms.append(stats.ms["diffusion"])
                    fluences.append(cd.scattered_fluence)
            scene = Scene(transfer_function=tf, lights=lights, albedo=ALBEDO,
                          anisotropy=ANISOTROPY)
            image = np.asarray(render_illuminated(
                vol, scene, render_size, render_size, device,
                illumination=cd.illumination_volume(vol)).radiance, dtype=np.float64)
            if reference is None:
                reference = (fluences, image)
            light = max(float(np.abs(f - g).max() / max(np.abs(g).max(), 1e-30))
                        for f, g in zip(fluences, reference[0]))
            picture = float(np.abs(image - reference[1]).mean()
                            / max(reference[1].mean(), 1e-30))
            print(f"| {label} | {'x'.join(map(str, light_dims))} | {count} | {tol:g} | "
                  f"{'/'.join(map(str, iterations))} | {np.median(ms):.2f} | {light:.1e} | "
                  f"{picture:.1e} |", flush=True)


def cube_case(n: int, device: str, lights=None, **optics):
    """A synthetic ``(2n)³`` volume and a solver for an ``n³`` light volume, updated with
    ``TF_A`` and ``lights`` (default: two, :func:`make_lights`)."""
    vol = synthetic((2 * n, 2 * n, 2 * n))
    cd = ConvectionDiffusionSolver(light_volume_shape=(n, n, n), device=device)
    cd.update(vol, TF_A, vol.mean_spacing(), make_lights(vol, 2) if lights is None else lights,
              **optics)
    return vol, cd


def light_size_table(sizes, device, repeats) -> None:
    print("\n### 2. Light-volume sizes (paper's Table 2): ms for one light and for the diffusion "
          "(cold start, to the default tolerance 1e-4)\n")
    print("| light volume | absorption (1 light, characteristics) | absorption (upwind) | "
          "scattering, paper (multigrid, iters) | scattering, physical (multigrid, iters) |")
    print("|---|---|---|---|---|")
    for n in sizes:
        vol, cd = cube_case(n, device, [DirectionalLight((1.0, -0.7, 0.3))], albedo=ALBEDO,
                            anisotropy=ANISOTROPY)
        sigma, h = cd._sigma, cd.spacing
        out = wp.empty_like(sigma)

        def sweep(scheme):
            convect_light(sigma, h, DIRECTIONAL, (1.0, -0.7, 0.3), out=out, scheme=scheme)
            wp.synchronize_device(device)

        absorption = median_ms(lambda: sweep("characteristics"), repeats)
        upwind = median_ms(lambda: sweep("upwind"), repeats)
        b = wp.array(cd.composed, dtype=wp.vec3, device=device)
        solver = DiffusionSolver((n, n, n), h, [(2.0 * h.max()) ** 2] * 3, "multigrid", device)
        reports = []

        def diffuse():
            x = wp.clone(b)
            reports.append(solver.solve(b, x, 100, 1e-4))
            wp.synchronize_device(device)

        scattering = median_ms(diffuse, repeats)
        rd = RadiativeDiffusion((n, n, n), h, device=device)
        rd.set_medium(cd._sigma, cd._color_sigma, ALBEDO, ANISOTROPY)
        q = wp.array(cd.source, dtype=wp.vec3, device=device)
        physical = []

        def diffuse_physical():
            x = wp.zeros_like(q)
            physical.append(rd.solve(q, x, 200, 1e-4, cold=True))
            wp.synchronize_device(device)

        physical_ms = median_ms(diffuse_physical, repeats)
        print(f"| {n}³ | {absorption:.2f} | {upwind:.2f} | {scattering:.2f} "
              f"({reports[-1].iterations}) | {physical_ms:.2f} ({physical[-1].iterations}) |")


def residual_table(n, device, repeats) -> None:
    vol, cd = cube_case(n, device)
    h = cd.spacing
    s = (4.0 * h.max()) ** 2
    b = wp.array(cd.composed, dtype=wp.vec3, device=device)
    caps = {"multigrid": 12, "cg": 300, "gauss-seidel": 3000, "dct": 1}
    marks = [0, 1, 2, 3, 4, 6, 8, 12, 16, 32, 64, 128, 256, 512, 1024, 2048, 3000]
    print(f"\n### 3. Relative residual vs iterations, light volume {n}³, sigma_hat_s = (4 h)² "
          f"(diffusion length 4 voxels), device {device_name(device)}\n")
    print("| solver | " + " | ".join(str(m) for m in marks) + " | ms / iteration | "
          "iterations to 1e-4 | ms to 1e-4 |")
    print("|---|" + "---|" * (len(marks) + 3))
    for method in SOLVERS:
        solver = DiffusionSolver((n, n, n), h, [s] * 3, method, device)
        x = wp.clone(b)
        solver.solve(b, x, 1, 1e-12)  # compile and warm up
        x = wp.clone(b)
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        report = solver.solve(b, x, caps[method], 1e-12)
        wp.synchronize_device(device)
        # Residual evaluations (one reduction + copy per iteration) are included.
        per_iter = 1000.0 * (time.perf_counter() - t0) / max(report.iterations, 1)
        res = report.residuals
        cells = [f"{res[m]:.1e}" if m < len(res) else "" for m in marks]
        hit = next((i for i, r in enumerate(res) if r <= 1e-4), None)
        to_tol = f"{hit}" if hit is not None else f">{len(res) - 1}"
        ms_tol = f"{hit * per_iter:.2f}" if hit is not None else ""
        print(f"| {method} | " + " | ".join(cells) + f" | {per_iter:.3f} | {to_tol} | {ms_tol} |")
    print(f"\n(float32 residual floor for this operator: {solver.floor:.1e})")
    cd.update(vol, TF_A, vol.mean_spacing(), make_lights(vol, 2), albedo=ALBEDO,
              anisotropy=ANISOTROPY)
    q = wp.array(cd.source, dtype=wp.vec3, device=device)
    print(f"\nPhysical model (albedo {ALBEDO}, g {ANISOTROPY}, nonlinear residual over the "
          "medium, cold start):\n")
    print("| solver | " + " | ".join(str(m) for m in marks) + " | ms / iteration | "
          "iterations to 1e-4 | ms to 1e-4 |")
    print("|---|" + "---|" * (len(marks) + 3))
    for method, cap in (("multigrid", 200), ("gauss-seidel", 3000)):
        rd = RadiativeDiffusion((n, n, n), h, device=device)
        rd.set_medium(cd._sigma, cd._color_sigma, ALBEDO, ANISOTROPY)
        rd.solve(q, wp.zeros_like(q), 1, 1e-12, method=method, cold=True)  # compile
        x = wp.zeros_like(q)
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        report = rd.solve(q, x, cap, 1e-6, method=method, cold=True)
        wp.synchronize_device(device)
        per_iter = 1000.0 * (time.perf_counter() - t0) / max(report.iterations, 1)
        res = report.residuals
        cells = [f"{res[m]:.1e}" if m < len(res) else "" for m in marks]
        hit = next((i for i, r in enumerate(res) if r <= 1e-4), None)
        to_tol = f"{hit}" if hit is not None else f">{len(res) - 1}"
        ms_tol = f"{hit * per_iter:.2f}" if hit is not None else ""
        print(f"| {method} | " + " | ".join(cells) + f" | {per_iter:.3f} | {to_tol} | {ms_tol} |")


def iterated_table(n, device) -> None:
    from vtkillum.core.convection_diffusion.convection import sweep_plan

    vol, cd = cube_case(n, device, [DirectionalLight((1.0, -0.7, 0.3))])
    sigma, h = cd._sigma, cd.spacing
    print(f"\n### 4. Convection of one light, light volume {n}³: one ordered sweep vs iterating "
          "to |ΔT| < 1e-6 (upwind: the paper's time steps, eq. 16, CFL 1/2; characteristics: "
          "Jacobi sweeps)\n")
    print("| light | scheme | sweep launches | sweep ms | iterations | iterated ms | "
          "max abs(T_sweep - T_iterated) |")
    print("|---|---|---|---|---|---|---|")
    for label, kind, vec in (("directional (1, -0.7, 0.3)", DIRECTIONAL, (1.0, -0.7, 0.3)),
                             ("point inside", 1, 0.4 * vol.extent)):
        for scheme in ("upwind", "characteristics"):
            convect_light(sigma, h, kind, vec, 2 * h.max(), scheme=scheme)
            wp.synchronize_device(device)
            t0 = time.perf_counter()
            swept = convect_light(sigma, h, kind, vec, 2 * h.max(), scheme=scheme)
            wp.synchronize_device(device)
            sweep_ms = 1000.0 * (time.perf_counter() - t0)
            t0 = time.perf_counter()
            iterated, steps = convect_light_iterated(sigma, h, kind, vec, 2 * h.max(),
                                                     tolerance=1e-6, scheme=scheme)
            wp.synchronize_device(device)
            it_ms = 1000.0 * (time.perf_counter() - t0)
            diff = float(np.abs(swept.numpy() - iterated.numpy()).max())
            launches = sweep_plan(kind, np.asarray(vec, float), (n, n, n), h, scheme).wavefronts
            print(f"| {label} | {scheme} | {launches} | {sweep_ms:.2f} | {steps} | {it_ms:.1f} | "
                  f"{diff:.1e} |")


def time_series_table(n, device, steps: int = 6) -> None:
    print(f"\n### 5. Time series ({steps} steps, light volume {n}³, sigma_hat_s = (4 h)²): "
          "diffusion iterations per step after the first\n")
    print("| model, solver | cold start | warm start | saved |")
    print("|---|---|---|---|")
    for model, method in (("paper", "multigrid"), ("paper", "cg"), ("paper", "gauss-seidel"),
                          ("physical", "multigrid")):
        counts = {}
        for warm in (False, True):
            cd = None
            its = []
            for t in range(steps):
                vol = synthetic((2 * n, 2 * n, 2 * n), phase=0.15 * t)
                if cd is None:
                    h = vol.extent / (n - 1)
                    cd = ConvectionDiffusionSolver(light_volume_shape=(n, n, n), solver=method,
                                                   scattering=[(4.0 * h.max()) ** 2] * 3,
                                                   diffusion_model=model, warm_start=warm,
                                                   device=device)
                stats = cd.update(vol, TF_A, vol.mean_spacing(), make_lights(vol, 2),
                                  volume_key=t, albedo=ALBEDO, anisotropy=ANISOTROPY)
                if t > 0:
                    its.append(stats.diffusion.iterations)
            counts[warm] = float(np.mean(its))
        print(f"| {model} {method} | {counts[False]:.1f} | {counts[True]:.1f} | "
              f"{counts[False] - counts[True]:.1f} ({100 * (1 - counts[True] / counts[False]):.0f} %) |")


def parse_sizes(values):
    rows = []
    names = {r[0].lower(): r for r in PAPER_TABLE_1}
    for v in values:
        if v == "paper":
            rows.extend(PAPER_TABLE_1)
        elif v.isdigit():
            n = int(v)
            rows.append((f"cube {n}", (n, n, n), (max(2, n // 2),) * 3, 2))
        elif v.lower() in names:
            rows.append(names[v.lower()])
        else:
            raise SystemExit(f"--sizes: {v!r} is neither 'paper', an integer nor one of "
                             f"{[r[0] for r in PAPER_TABLE_1]}")
    return rows


#: The tables ``--tables`` can pick (module docstring, items 1-7).
TABLES = ("stages", "sizes", "residual", "iterated", "series", "vcycle", "tolerance")
#: Bytes per cell a V(2,2) cycle must move at least on one level (vec3 float32 = 12 bytes
#: per array and cell): 4 red–black sweeps (each colour reads the whole x and its half of
#: b, writes its half of x: 24; the physical model also reads every face coefficient kx,
#: ky, kz, 36, and its half of the absorption-plus-leakage array, 6), the fused
#: residual-restriction (reads x, b and the coefficients: 24 or 72), the prolongation
#: (reads and writes x: 24) and the coarse grid's arrays (4.5).
VCYCLE_BYTES_PER_CELL = {"paper": 8 * 24 + 24 + 24 + 4.5,
                         "physical": 8 * (24 + 36 + 6) + 72 + 24 + 4.5}


def copy_bandwidth(device: str) -> float:
    """Achievable device memory bandwidth (bytes/s): a 512 MiB device-to-device copy."""
    a = wp.zeros(1 << 27, dtype=wp.float32, device=device)
    b = wp.zeros_like(a)
    wp.copy(b, a)
    wp.synchronize_device(device)
    t = time.perf_counter()
    for _ in range(10):
        wp.copy(b, a)
    wp.synchronize_device(device)
    return 10 * 2 * a.size * 4 / (time.perf_counter() - t)


def vcycle_table(sizes, device, repeats) -> None:
    """One multigrid V-cycle per model, replayed as a CUDA graph, against the memory
    traffic it needs at least (:data:`VCYCLE_BYTES_PER_CELL` over the levels, the coarsest
    grid's solve included) at the measured copy bandwidth."""
    from vtkillum.core.convection_diffusion.multigrid import Multigrid
    from vtkillum.core.graphs import LaunchGraphs

    bandwidth = copy_bandwidth(device)
    print(f"\n### 6. One multigrid V(2,2) cycle, device {device_name(device)} (copy bandwidth "
          f"{bandwidth / 1e12:.2f} TB/s; CUDA graph replay, median of {repeats} x 20)\n")
    print("| light volume | model | levels | ms / V-cycle | bytes moved (at least) | "
          "bandwidth limit ms | ratio to the limit |")
    print("|---|---|---|---|---|---|---|")
    for n in sizes:
        vol, cd = cube_case(n, device, albedo=ALBEDO, anisotropy=ANISOTROPY)
        h = cd.spacing
        b = wp.array(cd.composed, dtype=wp.vec3, device=device)
        mg = Multigrid((n, n, n), h, [(4.0 * h.max()) ** 2] * 3, device)
        rd = RadiativeDiffusion((n, n, n), h, device=device)
        rd.set_medium(cd._sigma, cd._color_sigma, ALBEDO, ANISOTROPY)
        q = wp.array(cd.source, dtype=wp.vec3, device=device)
        x2 = wp.zeros_like(q)
        rd.solve(q, x2, 3, 1e-12)  # lagged coefficients of a partly converged solution
        x = wp.clone(b)
        for model, shapes, cycle, coarse_bytes in (
                ("paper", mg.shapes, lambda: mg.vcycle(x, b),
                 3 * int(np.prod(mg.shapes[-1])) ** 2 * 4),
                ("physical", [lv.shape for lv in rd.levels], lambda: rd.vcycle(x2, q),
                 8 * 12 * int(np.prod(rd.levels[-1].shape)))):
            graphs = LaunchGraphs(device)
            graphs.run(("cycle",), cycle)
            wp.synchronize_device(device)

            def twenty():
                for _ in range(20):
                    graphs.run(("cycle",), cycle)
                wp.synchronize_device(device)
            ms = median_ms(twenty, repeats) / 20
            cells = sum(int(np.prod(sh)) for sh in shapes[:-1])
            moved = VCYCLE_BYTES_PER_CELL[model] * cells + coarse_bytes
            limit = 1e3 * moved / bandwidth
            print(f"| {n}³ | {model} | {len(shapes)} | {ms:.3f} | {moved / 1e6:.0f} MB | "
                  f"{limit:.3f} | {ms / limit:.1f}× |", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cuda if present)")
    ap.add_argument("--sizes", nargs="+", default=["paper"],
                    help="'paper' (Table 1 rows), row names, or cube edge lengths (half-size "
                         "light volume, 2 lights)")
    ap.add_argument("--light-sizes", type=int, nargs="+", default=[16, 32, 64, 128, 256])
    ap.add_argument("--solver-size", type=int, default=128)
    ap.add_argument("--iterated-size", type=int, default=64)
    ap.add_argument("--series-size", type=int, default=64)
    ap.add_argument("--render-size", type=int, default=512)
    ap.add_argument("--vcycle-sizes", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--tables", nargs="+", default=list(TABLES), choices=list(TABLES),
                    help="which tables to print (default: all)")
    ap.add_argument("--models", nargs="+", default=["physical", "paper"],
                    choices=["physical", "paper"],
                    help="diffusion models of the stages table (default: both)")
    ap.add_argument("--tolerance", type=float, default=1e-4,
                    help="relative residual of the stages table's diffusion (default 1e-4, "
                         "the solver's)")
    ap.add_argument("--tolerances", type=float, nargs="+", default=[1e-4, 3e-4, 1e-3],
                    help="tolerances of the tolerance table (the first is the reference)")
    args = ap.parse_args(argv)
    for tol in [args.tolerance, *args.tolerances]:
        if not 0.0 < tol < 1.0:
            ap.error(f"--tolerance and --tolerances must lie in (0, 1), got {tol:g}")
    device = resolve_device(args.device)
    # Compile every kernel once so that no table includes compilation.
    warm = synthetic((12, 12, 12))
    for model in ("physical", "paper"):
        ConvectionDiffusionSolver(scattering=[0.1] * 3, diffusion_model=model,
                                  device=device).update(warm, TF_A, warm.mean_spacing(),
                                                        make_lights(warm, 2))
    if "stages" in args.tables:
        for model in args.models:
            stage_table(parse_sizes(args.sizes), device, args.repeats, args.render_size, model,
                        args.tolerance)
    if "sizes" in args.tables:
        light_size_table(args.light_sizes, device, args.repeats)
    if "residual" in args.tables:
        residual_table(args.solver_size, device, args.repeats)
    if "iterated" in args.tables:
        iterated_table(args.iterated_size, device)
    if "series" in args.tables:
        time_series_table(args.series_size, device)
    if "vcycle" in args.tables:
        vcycle_table(args.vcycle_sizes, device, args.repeats)
    if "tolerance" in args.tables:
        tolerance_table(parse_sizes(args.sizes), device, args.tolerances, args.render_size)


if __name__ == "__main__":
    main()
