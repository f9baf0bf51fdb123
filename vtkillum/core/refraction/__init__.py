"""Refraction and caustics (Magnus & Bruckner, IEEE TVCG 2017).

Light and view rays bend in a refractive-index field and are propagated together,
plane by plane, through planes parallel to the image plane (numpy + warp only):

* :mod:`~vtkillum.core.refraction.optics` — the optical model of section 4.1: the
  refractive-index and medium-colour transfer functions ``η_tf``, ``m_tf``.
* :mod:`~vtkillum.core.refraction.ray_equation` — the ray equation (eqs. 6–8) and
  ``∇η`` by central differences.
* :mod:`~vtkillum.core.refraction.preintegration` — pre-integrated opacity, medium
  colour and particle colour between planes.
"""
