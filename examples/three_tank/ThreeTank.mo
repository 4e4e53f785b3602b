model ThreeTank
  "Three cylindrical tanks in series (T1 -> T3 -> T2 -> outlet), DTS200-like, with fault parameters"
  // Layout and parameter values after the Amira DTS200 three-tank laboratory plant as used
  // in the fault-diagnosis literature (e.g. S. X. Ding, Model-Based Fault Diagnosis
  // Techniques, Springer 2008, three-tank benchmark): tank cross-section 0.0154 m2, pipe
  // cross-section 5e-5 m2, pumps 0..1e-4 m3/s (100 ml/s); the outflow coefficients are
  // rounded typical values. Pump 1 feeds T1, pump 2 feeds T2; T1 drains into T3, T3 into T2,
  // T2 through its outlet. Flows follow Torricelli, q = a s_n sgn(d) sqrt(2 g |d|), with the
  // signed square root regularised as d / (d^2 + delta^2)^(1/4): equal to sgn(d) sqrt(|d|)
  // for |d| >> delta, smooth, and with the finite slope delta^(-1/2) at d = 0, so the
  // Jacobian stays finite when two levels are equal (or a tank is empty). The start values
  // (levels 0.4, 0.2, 0.3 m; pump flows 3.5017e-5, 2.4410e-5 m3/s) are a steady state to
  // better than 1e-8 m/s of level rate.
  parameter Real A(unit = "m2") = 0.0154 "tank cross-section";
  parameter Real s_n(unit = "m2") = 5e-5 "pipe cross-section";
  parameter Real az13 = 0.5 "outflow coefficient T1 -> T3";
  parameter Real az32 = 0.5 "outflow coefficient T3 -> T2";
  parameter Real az20 = 0.6 "outflow coefficient T2 -> outlet";
  final parameter Real g(unit = "m/s2") = 9.81 "gravity";
  final parameter Real delta(unit = "m") = 1e-3 "regularisation of the signed square root";
  parameter Real f_pump1 = 1 "fault: effectiveness of pump 1 (1 = healthy, 0 = dead)";
  parameter Real leak1(unit = "m2") = 0 "fault: leak area at the bottom of T1 (0 = healthy)";
  parameter Real clog13 = 0 "fault: clogging of the valve T1 -> T3 (0 = open, 1 = closed)";
  input Real q1(unit = "m3/s", start = 3.5017e-5) "pump 1 flow command (0 .. 1e-4)";
  input Real q2(unit = "m3/s", start = 2.4410e-5) "pump 2 flow command (0 .. 1e-4)";
  parameter Real q_unit(unit = "m3/s") = 1e-5 "flow of one unit of the disturbance input (10 ml/s)";
  input Real q_d(start = 0) "disturbance inflow into T3, in units of q_unit";
  Real h1(start = 0.4, fixed = true, unit = "m") "level of T1";
  Real h2(start = 0.2, fixed = true, unit = "m") "level of T2";
  Real h3(start = 0.3, fixed = true, unit = "m") "level of T3";
  Real q13(unit = "m3/s") "flow T1 -> T3";
  Real q32(unit = "m3/s") "flow T3 -> T2";
  Real q20(unit = "m3/s") "outflow of T2";
  Real q_leak(unit = "m3/s") "leak flow of T1";
  output Real y1(unit = "m") = h1 "measured level of T1";
  output Real y2(unit = "m") = h2 "measured level of T2";
  output Real y3(unit = "m") = h3 "measured level of T3";
equation
  q13 = (1 - clog13)*az13*s_n*sqrt(2*g)*(h1 - h3)/((h1 - h3)^2 + delta^2)^0.25;
  q32 = az32*s_n*sqrt(2*g)*(h3 - h2)/((h3 - h2)^2 + delta^2)^0.25;
  q20 = az20*s_n*sqrt(2*g)*h2/(h2^2 + delta^2)^0.25;
  q_leak = leak1*sqrt(2*g)*h1/(h1^2 + delta^2)^0.25;
  A*der(h1) = f_pump1*q1 - q13 - q_leak;
  A*der(h3) = q13 - q32 + q_unit*q_d;
  A*der(h2) = q2 + q32 - q20;
  annotation(experiment(StopTime = 600, Interval = 1));
end ThreeTank;
