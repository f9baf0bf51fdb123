"""Volumetric photon mapping with Historygrams (Jönsson, Kronander, Ropinski & Ynnerman 2012).

One module per stage of the paper (numpy + warp only):

* :mod:`~vtkillum.core.photon.emission` — photons leave the lights, importance-sampled
  by power (directional lights over the volume's projected box, point lights over the
  cone or sphere that holds the box).
* :mod:`~vtkillum.core.photon.tracing` — the random walk of section 3.2 (eqs. 6–7):
  free paths by ray marching the optical depth, Russian roulette with ``p = σs/σt``,
  Henyey–Greenstein directions, a maximum scattering order ``S_n``; every interaction is
  stored with its Historygram, and a photon can be retraced from any stored interaction.
* :mod:`~vtkillum.core.photon.storage` — the interaction buffer: an implicit linked list
  per photon path (contiguous, ordered by scattering order) and its compaction after a
  retrace.
* :mod:`~vtkillum.core.photon.hashgrid` — the spatial hash of section 5: keys sorted on
  the device with warp's radix sort, cell start tables, queries by rows of cells clipped
  to the photon sphere (cells of half the radius).
* :mod:`~vtkillum.core.photon.density` — the density estimate (eq. 8) at view samples
  and onto a grid (the illumination volume of :class:`PhotonDensityFilter`).
* :mod:`~vtkillum.core.photon.historygram` — Historygrams (eqs. 9–11): 64-bit masks over
  the data range, query masks from transfer-function edits (Fig. 3), the spatial
  Historygram (section 4.3.2).
* :mod:`~vtkillum.core.photon.segments` — view rays split into ``V_n`` segments, each with
  its radiance, transmittance and Historygram, composited by eq. (4).
* :mod:`~vtkillum.core.photon.mapper` — :class:`PhotonMapper`: keeps photons, hash and
  segments between frames, updates them incrementally after an edit, refines
  progressively while nothing changes.
* :mod:`~vtkillum.core.photon.render` — the ``"photon"`` render method.
"""
