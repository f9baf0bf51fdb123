"""ParaView side of the vtkillum plugin (imported by ``paraview_plugin/vtkillum_plugin.py``).

* :mod:`.glue` -- what the plugin's filter classes add to the library filters:
  the ``Lights`` table, ParaView's colour map and opacity function, errors in
  ParaView's words, the illumination arrays the render view reads.
* :mod:`.links` -- server-manager links: a filter takes the colour map, opacity
  function, unit distance and array of the display that shows it.
* :mod:`.display` -- renders illumination outputs in ParaView's render view
  (per-sample lighting in the GPU ray caster, see ``paraview_plugin/README.md``).
* :mod:`.tables` -- a table property (Lights, RefractiveIndex, MediumColor) set from
  Python to a list that is not a whole number of rows is refused with an error.
* :mod:`.x11` -- screen grabs and window closing for the GUI tests.

Only :mod:`.glue` is needed where the filters execute (a pvserver); the others
run in the client (the GUI, pvpython, pvbatch).
"""
