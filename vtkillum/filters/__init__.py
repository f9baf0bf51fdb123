"""VTK algorithms of vtkillum: one ``VTKPythonAlgorithmBase`` subclass per module.

Every illumination filter derives from
:class:`~vtkillum.filters.base.IlluminationFilterBase`, which holds the
transfer functions, lights, output resolution, device and per-time-step cache;
a filter implements only ``compute(volume, params) -> {name: array}``.
"""

from vtkillum.filters.ambient_extinction import AmbientExtinctionFilter
from vtkillum.filters.base import IlluminationFilterBase, IlluminationParameters
from vtkillum.filters.convection_diffusion_light import ConvectionDiffusionLightFilter
from vtkillum.filters.light_transmittance import LightTransmittanceFilter
from vtkillum.filters.many_lights import ManyLightsFilter
from vtkillum.filters.optical_properties import OpticalPropertiesFilter
from vtkillum.filters.photon_density import PhotonDensityFilter
from vtkillum.filters.refraction_render import RefractionRenderFilter

__all__ = [
    "AmbientExtinctionFilter",
    "ConvectionDiffusionLightFilter",
    "IlluminationFilterBase",
    "IlluminationParameters",
    "LightTransmittanceFilter",
    "ManyLightsFilter",
    "OpticalPropertiesFilter",
    "PhotonDensityFilter",
    "RefractionRenderFilter",
]
