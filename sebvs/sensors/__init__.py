"""Sensor models on a scene's physical light (sebvs.sim.light, sebvs.sim.radiance): the
frame camera after EMVA 1288, the rig that runs it beside the event sensor's light, and
their validation against the fields' standards."""
