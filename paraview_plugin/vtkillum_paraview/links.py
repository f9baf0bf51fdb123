"""Server-manager links: a vtkIllum filter takes what its display shows.

One transfer function (issue 12): the filters have no colour or opacity editor of
their own. Their hidden properties ``LookupTable`` and ``ScalarOpacityFunction``
hold ParaView's colour map and opacity function of the array they illuminate (the
proxies of the ``lookup_tables`` / ``piecewise_functions`` groups that the Color
Map Editor edits), and this module keeps them so:

* when a filter is registered (created in the GUI, by ``paraview.simple``, or
  loaded from a state file), it gets the colour map of its **Scalars** array
  (ParaView's, by array name; created and fitted to the data range if the array
  has none yet, as ParaView does when it first colours by an array);
* when its display colours by another array of the input (the toolbar's array
  list), the filter's **Scalars** follow; when the display takes another colour
  map or opacity function (e.g. *Use Separate Color Map*), so does the filter;
* when **Scalars** change in the filter's panel, the displays colour by the new
  array;
* **Scalar Opacity Unit Distance** of the display and the filter stay equal (the
  filter's 0 means ParaView's default for the display, the approximate cell length).

A filter whose output is a rendered picture (:data:`IMAGE_FILTERS`: the refraction
render) keeps the colour-map link, but its displays show the picture: coloured by its
RGB array with Map Scalars off, no scalar bar for it, and not linked back to Scalars.

Editing the colour map or the opacity function then re-executes the filter (its
VTK object watches their content, see :class:`vtkillum_paraview.glue.ParaViewGlue`),
and ParaView rescales them with the data as usual.

:func:`install` hooks the active session's proxy manager (idempotent); the plugin
calls it when it is loaded and whenever a filter object is created (a new session,
e.g. after *Reset Session*, gets hooked then). The same hook lets
:mod:`vtkillum_paraview.display` find new render views. Only client-side (builtin
sessions: the GUI without a server, pvpython, pvbatch).
"""

from __future__ import annotations

from paraview.modules.vtkRemotingServerManager import (
    vtkSMPropertyHelper,
    vtkSMProxyIterator,
    vtkSMProxyManager,
)
from paraview.modules.vtkRemotingViews import vtkSMTransferFunctionManager
from vtkmodules.util.misc import calldata_type
from vtkmodules.util.vtkConstants import VTK_STRING
from vtkmodules.vtkCommonCore import vtkWeakReference

from vtkillum.filters.refraction_render import RGB_ARRAY as REFRACTION_RGB

FILTER_PREFIX = "vtkIllum"
#: Filters whose output is a rendered picture (XML name -> its RGB array), not a volume on
#: the data's grid: their displays show the picture (Map Scalars off) and are not linked
#: to the transfer function (see :class:`ImageDisplayLink`).
IMAGE_FILTERS = {"vtkIllumRefractionRender": REFRACTION_RGB}
_ASSOCIATIONS = {"POINTS": 0, "CELLS": 1}

_hooked_managers: dict = {}  # id(pxm) -> (weak ref, tag)
_filters: dict = {}  # global id -> FilterLink
_displays: dict = {}  # global id -> DisplayLink
_scalar_bars: dict = {}  # global id -> PictureScalarBarLink
_busy = []  # re-entrance guard (property changes made here fire the same events)


def install() -> None:
    """Hook the active session's proxy manager (once per session)."""
    manager = vtkSMProxyManager.GetProxyManager()
    pxm = manager.GetActiveSessionProxyManager() if manager is not None else None
    if pxm is None:
        return
    key = pxm.GetAddressAsString("vtkSMSessionProxyManager")
    if key in _hooked_managers and _hooked_managers[key][0].Get() is not None:
        return
    ref = vtkWeakReference()
    ref.Set(pxm)
    tag = pxm.AddObserver("RegisterEvent", lambda obj, event: scan(obj))
    _hooked_managers[key] = (ref, tag)
    scan(pxm)


def scan(pxm) -> None:
    """Link every vtkIllum filter and display not linked yet; hook new render views."""
    if _busy:
        return
    _busy.append(True)
    try:
        _scan(pxm)
    except Exception as err:  # noqa: BLE001 - a link must never break the GUI
        _warn(f"vtkIllum: could not link filters and displays: {err}")
    finally:
        _busy.pop()


def _scan(pxm) -> None:
    if True:
        for proxy in _proxies(pxm, "sources"):
            if proxy.GetXMLName().startswith(FILTER_PREFIX) and proxy.GetGlobalID() not in _filters:
                _filters[proxy.GetGlobalID()] = FilterLink(proxy, pxm)
        for proxy in _proxies(pxm, "representations"):
            gid = proxy.GetGlobalID()
            if gid in _displays or not proxy.GetProperty("Input"):
                continue
            source = _input_proxy(proxy)
            if source is not None and source.GetGlobalID() in _filters and _followed_display(proxy):
                picture = IMAGE_FILTERS.get(source.GetXMLName())
                _displays[gid] = (ImageDisplayLink(proxy, picture) if picture
                                  else DisplayLink(proxy, _filters[source.GetGlobalID()]))
        for proxy in _proxies(pxm, "scalar_bars"):
            gid = proxy.GetGlobalID()
            if gid not in _scalar_bars and proxy.GetProperty("LookupTable") is not None:
                lut = vtkSMPropertyHelper(proxy, "LookupTable").GetAsProxy()
                name = pxm.GetProxyName("lookup_tables", lut) if lut is not None else None
                array = (name or "").rsplit(".PVLookupTable", 1)[0]
                if array in IMAGE_FILTERS.values():
                    _scalar_bars[gid] = PictureScalarBarLink(proxy, array)
        _prune()
        try:
            from vtkillum_paraview import display

            display.hook_views(_proxies(pxm, "views"))
        except ImportError:
            pass


def _prune() -> None:
    for table in (_filters, _displays, _scalar_bars):
        for gid in [gid for gid, link in table.items() if link.proxy is None]:
            del table[gid]


def _proxies(pxm, group: str) -> list:
    it = vtkSMProxyIterator()
    it.SetSessionProxyManager(pxm)
    it.SetModeToOneGroup()
    found, seen = [], set()
    it.Begin(group)
    while not it.IsAtEnd():
        proxy = it.GetProxy()
        if proxy is not None and proxy.GetGlobalID() not in seen:
            seen.add(proxy.GetGlobalID())
            found.append(proxy)
        it.Next()
    return found


def _input_proxy(representation):
    prop = representation.GetProperty("Input")
    return prop.GetProxy(0) if prop is not None and prop.GetNumberOfProxies() else None


def _followed_display(representation) -> bool:
    """Whether the links follow a display of a vtkIllum filter: one of its port 0 (the
    illumination, or the refraction render's picture) with a colour map and an opacity
    function. Other ports (Many Lights' virtual-light points: a polydata display without
    ``ScalarOpacityFunction``) are left alone: following them asked for a property they
    lack and coloured them by an array they do not have (two warnings on every Apply)."""
    prop = representation.GetProperty("Input")
    if prop is None or not prop.GetNumberOfProxies() or prop.GetOutputPortForConnection(0) != 0:
        return False
    return all(representation.GetProperty(name) is not None
               for name in ("ColorArrayName", "LookupTable", "ScalarOpacityFunction"))


class _Link:
    """A proxy held weakly, with one PropertyModifiedEvent observer."""

    def __init__(self, proxy) -> None:
        self._ref = vtkWeakReference()
        self._ref.Set(proxy)

        @calldata_type(VTK_STRING)
        def modified(caller, event, name=None):
            if _busy or not name:  # (some ParaView versions send no name: nothing to follow)
                return
            _busy.append(True)
            try:
                self.property_modified(name)
            except Exception as err:  # noqa: BLE001 - a link must never break the GUI
                _warn(f"vtkIllum: could not follow {name}: {err}")
            finally:
                _busy.pop()

        # The proxy holds the observer, the observer this link, the link only a weak
        # reference to the proxy: no cycle, the link dies with the proxy.
        self._tag = proxy.AddObserver("PropertyModifiedEvent", modified)

    @property
    def proxy(self):
        return self._ref.Get()

    def property_modified(self, name: str) -> None:  # pragma: no cover - overridden
        pass


class FilterLink(_Link):
    """A vtkIllum filter proxy: its colour map follows its Scalars array."""

    def __init__(self, proxy, pxm) -> None:
        super().__init__(proxy)
        self._pxm_ref = vtkWeakReference()
        self._pxm_ref.Set(pxm)
        self._default_scalars()
        self.link_transfer_functions()

    def _default_scalars(self) -> None:
        """Make Scalars name an array of the input (its active point scalars by default).

        Done now, as the GUI does when the input is up to date, so that the first
        execution already has the right colour map. ParaView 5.11 may default the
        property to an array coloured by elsewhere that the input does not have.
        """
        proxy = self.proxy
        source = _input_proxy(proxy)
        if source is None or not hasattr(source, "UpdatePipeline"):
            return
        name, _ = self.scalars()
        arrays = self.input_arrays()
        if name and name in arrays:
            return
        if not arrays:
            source.UpdatePipeline()
            arrays = self.input_arrays()
        if name and name in arrays:
            return
        points = source.GetDataInformation(0).GetPointDataInformation()
        active = points.GetAttributeInformation(0)  # vtkDataSetAttributes::SCALARS
        choice = active.GetName() if active is not None else None
        if not choice and points.GetNumberOfArrays():
            choice = points.GetArrayInformation(0).GetName()
        if choice:
            helper = vtkSMPropertyHelper(proxy, "SelectInputScalars")
            helper.SetInputArrayToProcess(0, choice)
            proxy.UpdateVTKObjects()

    # --- what the filter illuminates ------------------------------------------------------------
    def scalars(self) -> tuple[str | None, str]:
        """(array name, "POINTS"/"CELLS") of the Scalars property."""
        proxy = self.proxy
        prop = proxy.GetProperty("SelectInputScalars") if proxy is not None else None
        if prop is None:
            return None, "POINTS"
        helper = vtkSMPropertyHelper(prop)
        if helper.GetNumberOfElements() < 5:
            return None, "POINTS"
        name = helper.GetAsString(4) or None
        association = "CELLS" if helper.GetAsString(3) == "1" else "POINTS"
        return name, association

    def input_arrays(self) -> set:
        """Names of the input's point and cell arrays (from its data information)."""
        proxy = self.proxy
        source = _input_proxy(proxy) if proxy is not None else None
        if source is None:
            return set()
        info = source.GetDataInformation(0)
        names = set()
        for attributes in (info.GetPointDataInformation(), info.GetCellDataInformation()):
            for i in range(attributes.GetNumberOfArrays()):
                names.add(attributes.GetArrayInformation(i).GetName())
        return names

    def set_scalars(self, name: str, association: str = "POINTS") -> None:
        proxy = self.proxy
        helper = vtkSMPropertyHelper(proxy, "SelectInputScalars")
        helper.SetInputArrayToProcess(_ASSOCIATIONS.get(association, 0), name)
        proxy.UpdateVTKObjects()
        self.link_transfer_functions()

    # --- colour map and opacity function ---------------------------------------------------------
    def link_transfer_functions(self, lut=None, opacity=None) -> None:
        """Point the filter at ``lut``/``opacity`` (default: ParaView's of its Scalars array)."""
        proxy, pxm = self.proxy, self._pxm_ref.Get()
        if proxy is None or pxm is None:
            return
        if lut is None:
            name, _ = self.scalars()
            if not name:
                return
            lut, opacity = transfer_functions_for(name, pxm, self._range(name))
        if opacity is None:
            opacity = vtkSMPropertyHelper(lut, "ScalarOpacityFunction").GetAsProxy()
        changed = False
        for prop, value in (("LookupTable", lut), ("ScalarOpacityFunction", opacity)):
            helper = vtkSMPropertyHelper(proxy, prop)
            if value is not None and helper.GetAsProxy() is not value:
                helper.Set(value)
                changed = True
        if changed:
            proxy.UpdateVTKObjects()

    def _range(self, name: str):
        proxy = self.proxy
        source = _input_proxy(proxy) if proxy is not None else None
        if source is None:
            return None
        info = source.GetDataInformation(0).GetPointDataInformation().GetArrayInformation(name)
        if info is None:
            info = source.GetDataInformation(0).GetCellDataInformation().GetArrayInformation(name)
        if info is None:
            return None
        lo, hi = info.GetComponentRange(-1 if info.GetNumberOfComponents() > 1 else 0)
        return (lo, hi) if hi >= lo else None

    def property_modified(self, name: str) -> None:
        if name == "SelectInputScalars":
            self.link_transfer_functions()
            array, association = self.scalars()
            for link in list(_displays.values()):
                if link.filter is self and array:
                    link.colour_by(array, association)
        elif name == "ScalarOpacityUnitDistance":
            value = float(vtkSMPropertyHelper(self.proxy, name).GetAsDouble())
            if value > 0:
                for link in list(_displays.values()):
                    if link.filter is self:
                        link.set_unit_distance(value)


class DisplayLink(_Link):
    """A representation of a vtkIllum filter: the filter follows what it colours by."""

    def __init__(self, proxy, filter_link: FilterLink) -> None:
        super().__init__(proxy)
        self.filter = filter_link
        self._coloured_yet = False
        self.follow()

    def colour_array(self) -> tuple[str | None, str]:
        proxy = self.proxy
        if proxy is None or proxy.GetProperty("ColorArrayName") is None:
            return None, "POINTS"
        helper = vtkSMPropertyHelper(proxy, "ColorArrayName")
        name = helper.GetInputArrayNameToProcess() or None
        association = "CELLS" if helper.GetInputArrayAssociation() == 1 else "POINTS"
        return name, association

    def follow(self) -> None:
        """Make the filter take this display's array, colour map, opacity and unit distance."""
        proxy = self.proxy
        if proxy is None or self.filter.proxy is None:
            return
        name, association = self.colour_array()
        scalars, scalars_association = self.filter.scalars()
        if name and not self._coloured_yet:
            # ParaView's first choice of array: the illuminated one (ParaView 5.11 sometimes
            # picks another output array); later choices are the user's.
            self._coloured_yet = True
            if scalars and name != scalars and name != "illuminated_rgba" and \
                    name not in self.filter.input_arrays():
                self.colour_by(scalars, scalars_association)
                return
        if name and name != scalars and name in self.filter.input_arrays():
            self.filter.set_scalars(name, association)
            scalars = name
        if name and name == scalars:  # (a display of another array, e.g. the baked RGBA, is
            # left alone: its colour map and unit distance are not the filter's)
            lut = vtkSMPropertyHelper(proxy, "LookupTable", True).GetAsProxy()
            opacity = vtkSMPropertyHelper(proxy, "ScalarOpacityFunction", True).GetAsProxy()
            if lut is not None:
                self.filter.link_transfer_functions(lut, opacity)
            self._follow_unit_distance()

    def _follow_unit_distance(self) -> None:
        """The display's unit distance and the filter's stay equal. The first time, a value
        set on the filter goes to the display; afterwards the display's edits go to the filter."""
        proxy, fproxy = self.proxy, self.filter.proxy
        if proxy.GetProperty("ScalarOpacityUnitDistance") is None:
            return
        shown = float(vtkSMPropertyHelper(proxy, "ScalarOpacityUnitDistance").GetAsDouble())
        own = float(vtkSMPropertyHelper(fproxy, "ScalarOpacityUnitDistance").GetAsDouble())
        if not getattr(self, "_unit_linked", False):
            self._unit_linked = True
            if own > 0 and abs(own - shown) > 1e-9 * own:
                self.set_unit_distance(own)
                return
        default = _approximate_cell_length(fproxy)
        resolved = own if own > 0 else default
        if shown > 0 and abs(shown - resolved) > 1e-9 * max(shown, 1.0):
            vtkSMPropertyHelper(fproxy, "ScalarOpacityUnitDistance").Set(
                0.0 if default and abs(shown - default) <= 1e-9 * shown else shown)
            fproxy.UpdateVTKObjects()

    def set_unit_distance(self, value: float) -> None:
        proxy = self.proxy
        if proxy is None or self.colour_array()[0] != self.filter.scalars()[0]:
            return
        if proxy.GetProperty("ScalarOpacityUnitDistance") is not None:
            vtkSMPropertyHelper(proxy, "ScalarOpacityUnitDistance").Set(value)
            proxy.UpdateVTKObjects()

    def colour_by(self, name: str, association: str) -> None:
        proxy = self.proxy
        if proxy is None or self.colour_array()[0] == name:
            return
        if hasattr(proxy, "SetScalarColoring"):
            proxy.SetScalarColoring(name, _ASSOCIATIONS.get(association, 0))
            proxy.UpdateVTKObjects()
        self.follow()

    def property_modified(self, name: str) -> None:
        if name in ("ColorArrayName", "LookupTable", "ScalarOpacityFunction",
                    "ScalarOpacityUnitDistance"):
            self.follow()


class ImageDisplayLink(_Link):
    """A display of a rendered picture (:data:`IMAGE_FILTERS`): coloured by its RGB array it
    shows the colours directly (Map Scalars off), as an image viewer would."""

    def __init__(self, proxy, array: str) -> None:
        super().__init__(proxy)
        self.array = array
        self.filter = None  # (not linked to the filter's colour map: it shows a picture)
        self.follow()

    def follow(self) -> None:
        proxy = self.proxy
        if proxy is None or proxy.GetProperty("MapScalars") is None \
                or proxy.GetProperty("ColorArrayName") is None:
            return
        name = vtkSMPropertyHelper(proxy, "ColorArrayName").GetInputArrayNameToProcess()
        helper = vtkSMPropertyHelper(proxy, "MapScalars")
        if name == self.array and helper.GetAsInt() != 0:
            helper.Set(0)
            proxy.UpdateVTKObjects()

    def shows_colours_directly(self) -> bool:
        proxy = self.proxy
        if proxy is None or proxy.GetProperty("MapScalars") is None:
            return False
        name = vtkSMPropertyHelper(proxy, "ColorArrayName").GetInputArrayNameToProcess()
        return name == self.array and vtkSMPropertyHelper(proxy, "MapScalars").GetAsInt() == 0

    def property_modified(self, name: str) -> None:
        if name == "ColorArrayName":
            self.follow()
        if name in ("ColorArrayName", "MapScalars"):
            for link in list(_scalar_bars.values()):
                if link.array == self.array:
                    link.hide()


class PictureScalarBarLink(_Link):
    """The scalar bar of a picture's RGB array (:data:`IMAGE_FILTERS`) stays hidden while
    a display shows that array directly (Map Scalars off): the GUI shows one on Apply,
    before the display's Map Scalars is switched off, and it would label nothing."""

    def __init__(self, proxy, array: str) -> None:
        super().__init__(proxy)
        self.array = array
        self.hide()

    def hide(self) -> None:
        proxy = self.proxy
        direct = any(isinstance(link, ImageDisplayLink) and link.array == self.array
                     and link.shows_colours_directly() for link in list(_displays.values()))
        if proxy is None or not direct or proxy.GetProperty("Visibility") is None:
            return
        helper = vtkSMPropertyHelper(proxy, "Visibility")
        if helper.GetAsInt() != 0:
            helper.Set(0)
            proxy.UpdateVTKObjects()

    def property_modified(self, name: str) -> None:
        if name == "Visibility":
            self.hide()


def transfer_functions_for(name: str, pxm, data_range=None):
    """ParaView's colour map and opacity function of array ``name`` (the Color Map
    Editor's); when the array has none yet they are created and, given ``data_range``,
    fitted to it, as ParaView does when it first colours by an array."""
    existed = pxm.GetProxy("lookup_tables", f"{name}.PVLookupTable") is not None
    manager = vtkSMTransferFunctionManager()
    lut = manager.GetColorTransferFunction(name, pxm)
    opacity = manager.GetOpacityTransferFunction(name, pxm)
    if not existed and data_range is not None:
        lo, hi = data_range
        lut.RescaleTransferFunction(lo, hi, False)
        opacity.RescaleTransferFunction(lo, hi, False)
    return lut, opacity


def _approximate_cell_length(filter_proxy) -> float:
    import math

    source = _input_proxy(filter_proxy)
    if source is None:
        return 0.0
    info = source.GetDataInformation(0)
    bounds = info.GetBounds()
    if bounds[1] < bounds[0]:
        return 0.0
    diagonal = math.sqrt(sum((bounds[2 * a + 1] - bounds[2 * a]) ** 2 for a in range(3)))
    cells = info.GetNumberOfCells()
    return diagonal / cells ** (1.0 / 3.0) if cells > 0 and diagonal > 0 else 0.0


def _warn(message: str) -> None:
    from vtkmodules.vtkCommonCore import vtkOutputWindow

    vtkOutputWindow.GetInstance().DisplayWarningText(message + "\n")


__all__ = ["DisplayLink", "FilterLink", "ImageDisplayLink", "PictureScalarBarLink", "install",
           "scan", "transfer_functions_for"]
