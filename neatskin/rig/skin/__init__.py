"""The simulated skin: network physics, deformation model, sensitivity maps."""
