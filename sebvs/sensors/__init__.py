"""Sensor models on a scene's physical light (sebvs.sim.light, sebvs.sim.radiance): the
frame camera after EMVA 1288, the rig that runs it beside the event sensor's light, and
their validation against the fields' standards.

    from sebvs.sensors.framecam import FrameCamera, preset
    frame = FrameCamera(preset("mv_global_shutter"), (64, 64)).expose(luminance, t_end_s=0.1)

docs/sensors.md.
"""
