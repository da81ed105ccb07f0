"""Many tests open drivers on ``sim://`` ports directly, without building a simulated lab
(which is what registers the emulators' transports in the product): register them once here.
`test_transport.py` checks, in fresh interpreters, that a real lab never loads the simulator
and that a simulated lab registers its transports by itself."""

from normbox_lab.sim.transport import register_url_scheme

register_url_scheme()
