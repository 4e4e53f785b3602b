within;
model LinearJumpPlant
  "Linear plant whose matrices jump with the true fault mode (the plant of the LinearJumpPlant FMU of ftc-verify)"
  // Dimensions
  parameter Integer n(min=1) = 2 "Number of states";
  parameter Integer nu(min=0) = 2 "Number of control inputs";
  parameter Integer ny(min=0) = 1 "Number of outputs";
  parameter Integer nw(min=0) = 1 "Number of disturbance inputs";
  parameter Integer m(min=1) = 2 "Number of fault modes";
  parameter Integer q1(min=0) = 0 "Rows of Delta1 (0: no uncertainty in A)";
  parameter Integer p1(min=0) = 0 "Columns of Delta1";
  parameter Integer q2(min=0) = 0 "Rows of Delta2 (0: no uncertainty in B)";
  parameter Integer p2(min=0) = 0 "Columns of Delta2";

  // Matrices of the modes: first index = mode
  parameter Real A[m, n, n] "State matrices";
  parameter Real B[m, n, nu] "Input matrices";
  parameter Real C[m, ny, n] "Output matrices";
  parameter Real D[m, n, nw] "Disturbance matrices";
  parameter Real A1[m, n, q1] = zeros(m, n, q1) "Left weight of Delta1";
  parameter Real A2[m, p1, n] = zeros(m, p1, n) "Right weight of Delta1";
  parameter Real B1[m, n, q2] = zeros(m, n, q2) "Left weight of Delta2";
  parameter Real B2[m, p2, nu] = zeros(m, p2, nu) "Right weight of Delta2";
  parameter Real x0[n] = zeros(n) "Initial state";

  input Real u[nu] "Control input";
  input Real w[nw] "Disturbance input";
  input Integer mode(min=1, max=m, start=1) "True fault mode r (1..m)";
  input Real Delta1[q1, p1] "Uncertainty in A (the model assumes ||Delta1|| <= 1; not checked)";
  input Real Delta2[q2, p2] "Uncertainty in B (the model assumes ||Delta2|| <= 1; not checked)";
  output Real x[n] "State";
  output Real y[ny] "Output y = C[mode] x";

initial equation
  x = x0;
equation
  der(x) = (A[mode, :, :] + A1[mode, :, :] * Delta1 * A2[mode, :, :]) * x
         + (B[mode, :, :] + B1[mode, :, :] * Delta2 * B2[mode, :, :]) * u
         + D[mode, :, :] * w;
  y = C[mode, :, :] * x;

  annotation (Documentation(info="<html>
<p>The plant of the reference paper \"Synthesis of Fault Tolerant Control with Random FDI
Delay\" (Section II and IV) in its <em>true</em> fault mode <code>r = mode</code>:</p>
<pre>
  der(x) = (A[r] + A1[r] Delta1 A2[r]) x + (B[r] + B1[r] Delta2 B2[r]) u + D[r] w,
  y      = C[r] x.
</pre>
<p>This model is documentation for users with a Modelica tool. ftc-verify does not need
it: it builds the equivalent FMI 2.0 Co-Simulation FMU <code>LinearJumpPlant</code> from C
sources (<code>ftc_verify.fmu_build.build_fmu</code>), whose variables have the same names
(<code>u[k]</code>, <code>w[k]</code>, <code>mode</code>, <code>Delta1[i,j]</code>,
<code>Delta2[i,j]</code>, <code>x0[k]</code>, <code>x[k]</code>, <code>y[k]</code>).
The FMU also has the measured outputs <code>ym[k]</code> = <code>Cy[r] x</code> (row
<code>k</code>; <code>Cy = C</code> when the system gives no <code>Cy</code>) that
output-feedback controllers read; this model leaves them out (with <code>Cy = C</code>
they equal <code>y</code>).
The FMU integrates exactly for inputs held constant over each communication step; a
Modelica tool integrates this model numerically, so with inputs that are piecewise
constant on the same grid both agree up to the tool's solver tolerance.</p>
<p>Dimensions of zero (no uncertainty channel) are allowed: the corresponding products
are n x n (or n x nu) zero matrices.</p>
</html>"));
end LinearJumpPlant;
