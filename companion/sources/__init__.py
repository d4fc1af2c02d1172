"""Camera sources: the colour camera and the thermal camera behind one interface
(``base.FrameSource``; thermal frames are ``thermal.ThermalFrame``, temperatures in
°C). The colour camera is opened by ``colour_open``, the thermal one by
``thermal_open``; both reopen a lost device with backoff (``reopen``).

Adapters only: what a device or file gives, checked into typed frames. Imports the
config and fusion types, never the service, the vision or the reporting.
"""
