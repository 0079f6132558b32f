"""Runs: one simulated run as launch drives it through the simulator seam (:mod:`.run`), the
simulator on the bus that steps the world, owns simulated time and wires devices
(:mod:`.stepper`), the world process of a fleet (:mod:`.fleet_world`), and the bookkeeping of
what pushed the robot (:mod:`.disturbances`).

May import: every room of the simulator below it (backends, outputs, scenarios, render,
world), the device packages' components, and the framework; only :mod:`components.sim.plugin`
imports it.
"""
