"""The errors derive raises on bad input: one class per kind, all ModelError."""


class ModelError(ValueError):
    """A model, model file or generation request that derive cannot accept.

    The message always names the culprit: the matrix, the expected and actual
    shape, the symbol, the key or the path.
    """


class ShapeError(ModelError):
    """A matrix or vector has the wrong shape."""


class DtypeError(ModelError):
    """An array of the wrong floating-point type for a compiled kernel (float64 given to a
    float32 kernel, which would round it silently)."""


class SymbolError(ModelError):
    """An unknown, undeclared, repeated or badly named symbol."""


class NameError_(ModelError):
    """A model, state or measurement name that is not a usable identifier."""


class MatrixPropertyError(ModelError):
    """A matrix lacks a required property (symmetry, definiteness)."""


class ModelFileError(ModelError):
    """A model file that is not valid TOML or does not follow the format."""


class ExpressionError(ModelFileError):
    """An expression string that is not allowed (unsafe, too large, unknown name)."""


class SteadyStateError(ModelError):
    """A steady-state filter that cannot exist for the model (undetectable,
    unstabilisable, free symbols, bad FIR epsilon)."""


class OutputPathError(ModelError):
    """An output path that would write outside the output directory."""


class OutputWriteError(OutputPathError, OSError):
    """The output directory cannot be written (permissions, an immutable directory, a
    full disk, a name too long); also an OSError, whose errno it keeps."""


class FilterError(ModelError):
    """An unknown filter name or a filter that does not apply to the model."""


class OptionError(FilterError):
    """A filter option that is unknown, of the wrong type, out of range, or given for a
    filter that does not take it (derive.options)."""


class VerificationError(Exception):
    """Generated code disagrees with the reference beyond tolerance."""


#: How the message of a pattern check starts (header status lines, C wrappers read it).
PATTERN_MESSAGE_START = "P has a non-zero entry outside the pattern"


class PatternError(ValueError):
    """A generated filter was given a P (or P0) with a non-zero entry outside the sparsity
    pattern its code was generated for (the closure of the declared P0 pattern); the
    message names the entry, its value, the pattern and how to get code that accepts it."""


class NumericalError(ArithmeticError):
    """A generated or reference filter met a numerical failure (e.g. a failed Cholesky)."""


class NotFiniteError(MatrixPropertyError):
    """A matrix entry that is not a finite double at the given values (or whose exact value
    would be too large to compute)."""


class DomainError(NumericalError, ModelError):
    """A value of a free parameter outside the domain its symbol declares (a negative
    ``dt`` declared nonnegative), refused by derive's NumPy references and models as the
    generated code's check refuses it: a NumericalError like that check's, and a
    ModelError, since the value is bad input."""
