"""Table properties set from Python: a value that is not a whole number of rows is refused.

The vtkIllum filters have table properties: ``Lights`` (8 numbers a row) and the
refraction render's ``RefractiveIndex`` (Value, Eta) and ``MediumColor`` (Value, R, G,
B). ParaView declares them as repeated commands (``repeat_command``,
``number_of_elements_per_command``) and, given a flat list that is not a whole number
of rows, silently drops the numbers left over (``vtkSIVectorPropertyTemplate::Push``
sends ``len // n`` rows): ``f.RefractiveIndex = [0, 1, 1]`` would become the table
``0 1`` with no word. The GUI's table widget cannot produce such a list; Python can.

:func:`install` wraps ``paraview.servermanager.VectorProperty.SetData`` (what
``proxy.Property = value`` and ``SetPropertyWithName`` call) so that, for the table
properties of vtkIllum filters only, such a value is refused **before** the property
changes: the property and the filter keep their previous value, nothing executes
again, and the error goes to ParaView's output (the Output Messages window in the
GUI, stderr in pvpython/pvbatch) in ParaView's words, e.g.::

    vtkIllum Refraction Render: RefractiveIndex takes rows of 2 numbers (Value, Eta):
    got 3 numbers, which is not a whole number of rows. The previous value is kept:
    0 1.

No exception is raised (the other vtkIllum properties report a refused value the
same way: an error message naming the property, no traceback). Every other
property, and every other proxy, goes through ParaView's own ``SetData`` unchanged.
"""

from __future__ import annotations

FILTER_PREFIX = "vtkIllum"
_MARK = "_vtkillum_table_check"


def install() -> None:
    """Wrap ``VectorProperty.SetData`` once per Python session (idempotent)."""
    try:
        from paraview import servermanager
    except ImportError:  # no client-side Python (a pvserver): nothing to check
        return
    original = servermanager.VectorProperty.SetData
    if getattr(original, _MARK, False):
        return

    def SetData(self, values):
        rows = table_shape(self)
        if rows is not None:
            if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
                values = (values,)
            values = list(values)
            if len(values) % rows[0]:
                report(table_error(self, len(values), *rows))
                return None
        return original(self, values)

    setattr(SetData, _MARK, True)
    SetData.__doc__ = original.__doc__
    SetData.__wrapped__ = original
    servermanager.VectorProperty.SetData = SetData


def table_shape(prop) -> tuple[int, tuple] | None:
    """``(numbers per row, column labels)`` of a vtkIllum filter's table property
    (repeated, several numbers a command), ``None`` for any other property."""
    try:
        smprop = prop.SMProperty
        proxy = prop.Proxy.SMProxy
        if not proxy.GetXMLName().startswith(FILTER_PREFIX) or not smprop.GetRepeatable():
            return None
        per_row = int(smprop.GetNumberOfElementsPerCommand())
    except Exception:  # noqa: BLE001 - anything unexpected: ParaView's own behaviour
        return None
    if per_row < 2:
        return None
    return per_row, column_labels(smprop, per_row)


def column_labels(smprop, per_row: int) -> tuple:
    """The ``ShowComponentLabels`` hint of a property (the table's column titles)."""
    labels = [""] * per_row
    hints = smprop.GetHints()
    element = hints.FindNestedElementByName("ShowComponentLabels") if hints else None
    if element is not None:
        for i in range(element.GetNumberOfNestedElements()):
            child = element.GetNestedElement(i)
            try:
                component = int(child.GetAttribute("component"))
            except (TypeError, ValueError):
                continue
            if 0 <= component < per_row:
                labels[component] = child.GetAttribute("label") or ""
    return tuple(labels) if all(labels) else ()


def table_error(prop, count: int, per_row: int, labels: tuple) -> str:
    """The message for a value of ``count`` numbers given to a table of ``per_row``."""
    proxy = prop.Proxy.SMProxy
    name = proxy.GetPropertyName(prop.SMProperty) or "the table"
    columns = f" ({', '.join(labels)})" if labels else ""
    previous = [prop.SMProperty.GetElement(i)
                for i in range(prop.SMProperty.GetNumberOfElements())]
    kept = " ".join(f"{v:g}" for v in previous) if previous else "(none)"
    return (f"{proxy.GetXMLLabel()}: {name} takes rows of {per_row} numbers{columns}: got "
            f"{count} number{'s' if count != 1 else ''}, which is not a whole number of rows. "
            f"The previous value is kept: {kept}.")


def report(message: str) -> None:
    """An error in ParaView's output (no traceback)."""
    from vtkmodules.vtkCommonCore import vtkOutputWindow

    vtkOutputWindow.GetInstance().DisplayErrorText(message + "\n")


__all__ = ["install", "table_error", "table_shape"]
