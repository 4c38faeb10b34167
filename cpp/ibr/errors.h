// Typed errors raised by the checking front of each operation (never by kernels).
// The binding layer maps each to its Python class in ibrtools.errors.
#pragma once
#include <stdexcept>
#include <string>

namespace ibr {

struct ShapeError : std::invalid_argument { using std::invalid_argument::invalid_argument; };
struct DtypeError : std::invalid_argument { using std::invalid_argument::invalid_argument; };
struct BadValueError : std::invalid_argument { using std::invalid_argument::invalid_argument; };
struct InternalError : std::runtime_error { using std::runtime_error::runtime_error; };

}  // namespace ibr
