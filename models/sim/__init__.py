"""The ground-truth simulator: section III experiments, concealable effects, CAN/INS sensors.
Imports hmpc.models.plant, params and logs (channel names); never controller or tools.
"""
