"""Borrowed array views: the one place where compiled code skips reference counting.

Numba counts references to every array it passes to a compiled function: a
callee increments the count of each array argument on entry and decrements it
on exit, with an *atomic* instruction on the array's memory record. In the
ray walks a helper is called per point and per primitive with a dozen arrays,
so these atomic operations cost more than the arithmetic (a third of one
thread's time on a dense lattice); with two threads passing the same shared
array (the segment table) the record's cache line also travels between cores
at every call.

:func:`borrow` returns a view of an array with no memory record: Numba's
increment and decrement skip a null record, so passing the view costs
nothing. A borrowed view does not keep its memory alive; the rules, which
every caller follows:

* borrow an *argument* of the kernel (the caller's array outlives the call),
  or an array the kernel allocated and passes to :func:`keep_alive` after its
  last use through any view;
* never return a borrowed view, store it in a container, or let it escape the
  kernel that borrowed it.

A kernel compiled with :data:`slicer._jit.unrefcounted_kernel` counts no
references at all, whatever arrays it is given; borrowing serves the kernels
that keep Numba's runtime because they allocate (the bucket launchers) and the
calls they make.
"""
from __future__ import annotations

from numba import types
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array


def _borrowed(context, builder, aryty, value):
    """LLVM value of a borrowed view of the array ``value`` of type ``aryty``."""
    src = make_array(aryty)(context, builder, value=value)
    dst = make_array(aryty)(context, builder)
    populate_array(dst, data=src.data, shape=src.shape, strides=src.strides, itemsize=src.itemsize,
                   meminfo=None, parent=None)
    return dst._getvalue()


@intrinsic
def borrow(typingctx, arrs):
    """Views of ``arrs`` (same data, shape and strides) without a memory record.

    Parameters
    ----------
    arrs : array, or tuple of arrays
        Any Numba arrays.

    Returns
    -------
    array, or tuple of arrays
        Of ``arrs``' type; passing them to functions does no reference
        counting. Valid while ``arrs`` are (see the module docstring).
    """
    if isinstance(arrs, types.Array):
        def codegen(context, builder, sig, args):
            return _borrowed(context, builder, arrs, args[0])

        return arrs(arrs), codegen
    if isinstance(arrs, types.BaseTuple) and all(isinstance(t, types.Array) for t in arrs.types):
        def codegen_tuple(context, builder, sig, args):
            views = [_borrowed(context, builder, t, builder.extract_value(args[0], k))
                     for k, t in enumerate(arrs.types)]
            return context.make_tuple(builder, sig.return_type, views)

        return arrs(arrs), codegen_tuple
    return None


@intrinsic
def keep_alive(typingctx, arrs):
    """Use ``arrs`` (a tuple of arrays) here, so that Numba frees none of them
    before this point: call it after the last use of views borrowed from
    arrays the kernel allocated. Generates no code.
    """
    if not isinstance(arrs, types.BaseTuple):
        return None

    def codegen(context, builder, sig, args):
        return context.get_dummy_value()

    return types.none(arrs), codegen
