"""Refraction and caustics (Magnus & Bruckner, IEEE TVCG 2017).

Light and view rays bend in a refractive-index field and are propagated together,
plane by plane, through planes parallel to the image plane (numpy + warp only):

* :mod:`~vtkillum.core.refraction.optics` — the optical model of section 4.1: the
  refractive-index and medium-colour transfer functions ``η_tf``, ``m_tf``.
* :mod:`~vtkillum.core.refraction.ray_equation` — the ray equation (eqs. 6–8) and
  ``∇η`` by central differences.
* :mod:`~vtkillum.core.refraction.preintegration` — pre-integrated opacity, medium
  colour and particle colour between planes.
* :mod:`~vtkillum.core.refraction.planes` — the planes, the light grid sheared along
  the light, the per-frame record.
* :mod:`~vtkillum.core.refraction.light_propagation` — section 4.2: backward
  integration of the light buffer, the intensity law (caustics), the elliptical blur.
* :mod:`~vtkillum.core.refraction.view_rays` — section 4.3: forward integration of the
  view rays, diffuse and Cook–Torrance shading, eq. 14's compositing.
* :mod:`~vtkillum.core.refraction.sweep` — Algorithm 1: buffers, one light launch per
  plane, the view rays in chunks of planes.
* :mod:`~vtkillum.core.refraction.environment` — the mip-mapped environment map seen
  along the final ray directions (section 4.4).

:mod:`~vtkillum.core.refraction.render` is the ``"refraction"`` render method.
"""
