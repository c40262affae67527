"""The sensor's physics: network solver, deformation model, skin model, sensitivity maps, synthetic rows."""
