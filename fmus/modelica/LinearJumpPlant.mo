// The LinearJumpPlant of examples/paper.toml (the paper's Section VI plant) as a flat
// Modelica model that `ftc-verify build-fmu` compiles (pymoca + CasADi, no Modelica tool).
// Generated; regenerate for another system with
//   python -c "from ftc_verify.model.files import load_system; from ftc_verify.plants.linear_jump_modelica import linear_jump_modelica; print(linear_jump_modelica(load_system('SYSTEM.toml'), 'LinearJumpPlant'), end='')"
// tests/test_linear_jump_modelica.py checks that this file equals the generator's output,
// builds it, and compares its paths with the C LinearJumpPlant FMU.
model LinearJumpPlant
  "LinearJumpPlant of ftc-verify for one system (generated)"
  parameter Real mode(min = 1, max = 2) = 1 "true fault mode r (1..m)";
  input Real u[2] "control input";
  input Real w[1] "disturbance input";
  input Real Delta1[2, 2] "uncertainty in A";
  input Real Delta2[2, 2] "uncertainty in B";
  Real x[2](each start = 0, each fixed = true) "state";
  output Real y[1] "performance output y = C[r] x";
  output Real ym[1] "measured output ym = Cy[r] x";
equation
  der(x[1]) = (1.0)*x[1] + (if mode < 1.5 then 1.0 else 0.2)*u[2] + (0.5)*w[1] + (0.1)*Delta1[1,1]*((0.1)*x[1]) + (0.1)*Delta1[1,2]*((0.1)*x[2]) + (0.1)*Delta2[1,1]*((0.1)*u[1]) + (0.1)*Delta2[1,2]*((0.1)*u[2]);
  der(x[2]) = (0.8)*x[2] + (-0.25)*u[1] + (if mode < 1.5 then 0.25 else 0.05)*u[2] + (if mode < 1.5 then 0.5 else 1.0)*w[1] + (0.1)*Delta1[2,1]*((0.1)*x[1]) + (0.1)*Delta1[2,2]*((0.1)*x[2]) + (0.1)*Delta2[2,1]*((0.1)*u[1]) + (0.1)*Delta2[2,2]*((0.1)*u[2]);
  y[1] = (1.0)*x[1] + (2.0)*x[2];
  ym[1] = (1.0)*x[1] + (2.0)*x[2];
end LinearJumpPlant;
