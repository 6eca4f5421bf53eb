"""The ground-truth simulator: section III experiments (their plans, the driver, the truth plant
with concealable effects, the recording's CAN/INS sensors), live sensors and scenarios.
Imports hmpc.models.plant, params and logs (channel names); never controller or tools.
"""
