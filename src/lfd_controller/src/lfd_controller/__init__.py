"""Learning from demonstration: continuous inverse optimal control and a receding-horizon controller."""
