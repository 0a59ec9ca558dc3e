"""The INS/GNSS application of the catalog model ``ins_gnss`` (docs/navigation.md): the simulated
flight (flight, quaternion, constants), a NumPy reference EKF written by hand (reference),
how runs are compared and measured (compare), the generated EKF over a flight (run), and
the benchmark peers of the same functions (symforce_ekf, casadi_ekf, filterpy_ekf, with the
C timing loops of c_loop). docs/navigation.md describes them.
"""
