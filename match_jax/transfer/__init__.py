"""Transfer: a policy exported as one ONNX file (`export`), the MuJoCo C robot stand-in that runs it
without JAX (`standin`), and the stand-in protocol's report (`report`). The top layer."""
