"""Second-order forward-mode automatic differentiation for small batched functions (no ROS).

A Jet carries a batch of values with their gradients and Hessians with respect to n inputs:
val (B,), grad (B, n), hess (B, n, n) - or hess None when only first derivatives are wanted
(planning), which skips the Hessian arithmetic. The features use it, so their exact Hessians (which inverse
optimal control needs) come from the same code as their values.
"""
import numpy as np


class Jet:
    __array_priority__ = 100  # numpy arrays defer to Jet's operators

    def __init__(self, val, grad, hess):
        self.val, self.grad, self.hess = val, grad, hess

    @classmethod
    def variables(cls, values: np.ndarray, hessian: bool = True) -> list:
        """One Jet per column of values (B, n), each seeded with its unit gradient (hessian
        False: first derivatives only)."""
        values = np.asarray(values, dtype=float)
        batch, n = values.shape
        jets = []
        for i in range(n):
            grad = np.zeros((batch, n))
            grad[:, i] = 1.0
            jets.append(cls(values[:, i].copy(), grad, np.zeros((batch, n, n)) if hessian else None))
        return jets

    def _lift(self, other):
        if isinstance(other, Jet):
            return other
        value = np.broadcast_to(np.asarray(other, dtype=float), self.val.shape)
        return Jet(value, np.zeros_like(self.grad), None if self.hess is None else np.zeros_like(self.hess))

    def __add__(self, other):
        if not isinstance(other, Jet):
            return Jet(self.val + np.asarray(other, dtype=float), self.grad, self.hess)
        hess = None if self.hess is None else self.hess + other.hess
        return Jet(self.val + other.val, self.grad + other.grad, hess)

    __radd__ = __add__

    def __neg__(self):
        return Jet(-self.val, -self.grad, None if self.hess is None else -self.hess)

    def __sub__(self, other):
        return self + (-self._lift(other))

    def __rsub__(self, other):
        return self._lift(other) - self

    def __mul__(self, other):
        if not isinstance(other, Jet):
            scale = np.asarray(other, dtype=float)
            hess = None
            if self.hess is not None:
                hess = self.hess * scale[..., None, None] if scale.ndim else self.hess * scale
            return Jet(self.val * scale, self.grad * scale[..., None] if scale.ndim else self.grad * scale,
                       hess)
        grad = self.val[:, None] * other.grad + other.val[:, None] * self.grad
        if self.hess is None:
            return Jet(self.val * other.val, grad, None)
        outer = self.grad[:, :, None] * other.grad[:, None, :]
        return Jet(self.val * other.val, grad,
                   self.val[:, None, None] * other.hess + other.val[:, None, None] * self.hess
                   + outer + np.swapaxes(outer, 1, 2))

    __rmul__ = __mul__

    def __truediv__(self, other):
        if not isinstance(other, Jet):
            return self * (1.0 / np.asarray(other, dtype=float))
        return self * other.reciprocal()

    def __rtruediv__(self, other):
        return self.reciprocal() * other

    def _unary(self, value, first, second):
        if self.hess is None:
            return Jet(value, first[:, None] * self.grad, None)
        outer = self.grad[:, :, None] * self.grad[:, None, :]
        return Jet(value, first[:, None] * self.grad,
                   first[:, None, None] * self.hess + second[:, None, None] * outer)

    def reciprocal(self):
        inv = 1.0 / self.val
        return self._unary(inv, -inv ** 2, 2.0 * inv ** 3)

    def sqrt(self):
        root = np.sqrt(self.val)
        return self._unary(root, 0.5 / root, -0.25 / (root * self.val))

    def exp(self):
        value = np.exp(self.val)
        return self._unary(value, value, value)

    def cos(self):
        return self._unary(np.cos(self.val), -np.sin(self.val), -np.cos(self.val))

    def sin(self):
        return self._unary(np.sin(self.val), np.cos(self.val), -np.sin(self.val))

    def square(self):
        return self._unary(self.val ** 2, 2.0 * self.val, np.full_like(self.val, 2.0))
