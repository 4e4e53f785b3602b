within;
model LinearJumpPlantPaperExample
  "Open-loop plant of Section VI of the reference paper; the fault (mode 2) occurs at t = 5 s"
  LinearJumpPlant plant(
    n=2, nu=2, ny=1, nw=1, m=2, q1=2, p1=2, q2=2, p2=2,
    A={{{1.0, 0.0}, {0.0, 0.8}}, {{1.0, 0.0}, {0.0, 0.8}}},
    B={{{0.0, 1.0}, {-0.25, 0.25}}, {{0.0, 0.2}, {-0.25, 0.05}}},
    C={{{1.0, 2.0}}, {{1.0, 2.0}}},
    D={{{0.5}, {0.5}}, {{0.5}, {1.0}}},
    A1={{{0.1, 0.0}, {0.0, 0.1}}, {{0.1, 0.0}, {0.0, 0.1}}},
    A2={{{0.1, 0.0}, {0.0, 0.1}}, {{0.1, 0.0}, {0.0, 0.1}}},
    B1={{{0.1, 0.0}, {0.0, 0.1}}, {{0.1, 0.0}, {0.0, 0.1}}},
    B2={{{0.1, 0.0}, {0.0, 0.1}}, {{0.1, 0.0}, {0.0, 0.1}}},
    x0={0.0, 0.0});
equation
  plant.u = zeros(2);
  plant.w = {exp(-0.1*time)*sin(time)} "the paper's disturbance";
  plant.mode = if time < 5 then 1 else 2;
  plant.Delta1 = zeros(2, 2);
  plant.Delta2 = zeros(2, 2);
  annotation (experiment(StopTime=10));
end LinearJumpPlantPaperExample;
