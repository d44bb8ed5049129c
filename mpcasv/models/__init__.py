"""The vessel model (Fossen 3-DOF, CasADi), its parameters and identification; AUV motion
and behaviours; the acoustic channel and INS drift."""
