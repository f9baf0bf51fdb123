"""Small test volumes for the distributed tests (fixed seeds, the same on every rank)."""

import numpy as np

#: Whole shapes whose longest axis is x, y or z: VTK's split cuts the longest axis first, so
#: on 2 ranks these split along x, y and z (on 4 ranks along that axis and the next).
SHAPES = {"x": (21, 13, 11), "y": (11, 21, 13), "z": (13, 11, 21)}
SPACING = (0.5, 0.5, 0.5)
ORIGIN = (1.0, 2.0, 3.0)


def blobs(shape, seed: int = 3) -> np.ndarray:
    """Six Gaussian blobs (width about two voxels) in [-1, 1]^3: shadows with edges."""
    x, y, z = np.meshgrid(*[np.linspace(-1, 1, n) for n in shape], indexing="ij")
    f = np.zeros(shape)
    for c in np.random.default_rng(seed).uniform(-0.7, 0.7, (6, 3)):
        f += np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / 0.1)
    return f.astype(np.float32)


def whole_extent(shape) -> tuple:
    """VTK extent of a whole volume of ``shape`` points starting at index 0."""
    return (0, shape[0] - 1, 0, shape[1] - 1, 0, shape[2] - 1)


def piece_volume(field, extent, whole):
    """The Volume of one piece (the whole volume's placement of its points)."""
    from vtkillum.core.parallel import sub_slices
    from vtkillum.core.volume import Volume

    first = np.asarray(extent[0::2]) - np.asarray(whole[0::2])
    return Volume(field[sub_slices(extent, whole)], SPACING,
                  np.asarray(ORIGIN) + first * np.asarray(SPACING))


def piece_centre(extent) -> np.ndarray:
    """World position of the centre of a piece of the test volume."""
    mid = np.array([(extent[2 * a] + extent[2 * a + 1]) / 2 for a in range(3)])
    return np.asarray(ORIGIN) + mid * np.asarray(SPACING)
