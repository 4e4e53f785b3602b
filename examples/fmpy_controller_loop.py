"""The paper's loop written by hand in FMPy: the plant FMU and the exported controller FMU.

usage: python fmpy_controller_loop.py paper_K.fmu

The plant is the LinearJumpPlant FMU of examples/paper.toml (built by ftc-verify, cached);
the controller is the FMU `ftc-verify export-controller` wrote. A fault (mode 2) occurs at
t = 1 s and the FDI detects it at t = 1.5 s; both FMUs step with the controller's period.
"""

import shutil
import sys

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from ftc_verify.model.files import load_system
from ftc_verify.plants.linear_jump import build_fmu

UNZIPPED = []  # the extracted FMUs, removed at the end


def open_fmu(path, name):
    """Instantiate a co-simulation FMU; return it and its value references by name."""
    md = read_model_description(path)
    unzipped = extract(path)
    UNZIPPED.append(unzipped)
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    return fmu, {v.name: v.valueReference for v in md.modelVariables}


plant, pv = open_fmu(str(build_fmu(load_system("paper.toml"))), "plant")
ctrl, cv = open_fmu(sys.argv[1], "controller")
h = ctrl.getReal([cv["samplePeriod"]])[0]  # the period the controller was exported with
plant.setReal([pv["x0[1]"], pv["x0[2]"]], [1.0, -1.0])  # initial state
plant.exitInitializationMode()
ctrl.exitInitializationMode()

x_refs = [pv["x[1]"], pv["x[2]"]]
v_refs = [cv["v[1]"], cv["v[2]"]]
u_ctrl = [cv["u[1]"], cv["u[2]"]]
u_plant = [pv["u[1]"], pv["u[2]"]]
K = [np.array([[2.4563, 29.4954], [-21.0010, -7.5161]]), np.array([[1.9998, 24.5445], [-12.4093, -3.2219]])]
worst = 0.0
steps = round(6.0 / h)
for k in range(steps + 1):
    t = k * h
    fault, fdi = (2 if t >= 1.0 else 1), (2 if t >= 1.5 else 1)
    plant.setInteger([pv["mode"]], [fault])  # the true fault mode
    x = plant.getReal(x_refs)
    ctrl.setInteger([cv["fdi_mode"]], [fdi])  # the FDI's decision
    ctrl.setReal(v_refs, x)  # state feedback: v = x
    u = ctrl.getReal(u_ctrl)
    worst = max(worst, float(np.max(np.abs(np.array(u) - K[fdi - 1] @ x))))
    if k % round(1.0 / h) == 0:
        print(f"t = {t:3.1f} s  fault mode {fault}  FDI mode {fdi}  |x| = {np.linalg.norm(x):.4f}")
    if k == steps:
        break
    plant.setReal(u_plant, u)
    plant.doStep(currentCommunicationPoint=t, communicationStepSize=h)
    ctrl.doStep(currentCommunicationPoint=t, communicationStepSize=h)
print(f"largest |u - K x| over the run: {worst:.1e}")
for fmu in (plant, ctrl):
    fmu.terminate()
    fmu.freeInstance()
for folder in UNZIPPED:
    shutil.rmtree(folder, ignore_errors=True)
