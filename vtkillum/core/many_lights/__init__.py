"""Many-light volume rendering with transmittance caching (Weber, Kaplanyan, Stamminger &
Dachsbacher 2015).

Multiple scattering is carried by *virtual lights* (VLs): the scattering vertices of
random walks that start at the real lights. A view ray receives their single
scattering (eqs. 4–5), the real lights' single scattering is the project's exact
``single`` term, and the two together converge to the path tracer as VL sets
accumulate. One module per stage of the paper (numpy + warp only):

* :mod:`~vtkillum.core.many_lights.walk` — sections 3.1–3.2 and Algorithm 1: light
  paths with ray-marched or delta-tracked distance sampling (or the mean transmittance
  of eq. 8 for a global density scale), Russian roulette, HG sampling; every vertex is
  stored with its sampling density so that its contribution can be re-evaluated.
* :mod:`~vtkillum.core.many_lights.contribution` — eq. 6: optical depths of the stored
  path segments and the VL contributions ``L_i f_j`` re-evaluated along the stored
  vertex chains (after generation and after every edit).
* :mod:`~vtkillum.core.many_lights.avsm` — section 3.4: one adaptive volumetric shadow
  map per VL (a cube map of ``m`` (depth, transmittance) nodes per texel, Salvi et al.
  2010 insertion and compression), trilinear or point lookup.
* :mod:`~vtkillum.core.many_lights.gather` — eqs. 4–5: view rays gather the VLs
  (virtual point or spherical lights), exact single scattering from the real lights.
* :mod:`~vtkillum.core.many_lights.vlset` — the VL set of one seed: path table,
  vertex arrays, AVSM slots, and the progressive regeneration of sections 4–5.
* :mod:`~vtkillum.core.many_lights.cache` — what an edit invalidates (transfer
  function, density scale, colour/albedo/g, lights) and the immediate update.
* :mod:`~vtkillum.core.many_lights.render` — the ``"many-lights"`` render method and
  the progressive :class:`~vtkillum.core.many_lights.render.ManyLightsRenderer`.
"""
