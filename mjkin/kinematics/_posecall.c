/* One-configuration poses without numba's dispatch: the short path of Tree.pose and Tree.fk.
 *
 * A call through numba's compiled Python wrapper unboxes each array argument (~0.2 us for
 * three, as long as a 7-DoF arm's pose itself). This module takes a chain and a q, checks
 * in C that q is what the kernels read (a float64 ndarray, 1-D, C-contiguous, aligned,
 * native byte order), makes the output array and calls the kernel through a plain C
 * function pointer: numba's cfuncs over chain_pose and chain_poses
 * (mjkin/kinematics/chain.py), bound once with bind() on the first one-q pose (nothing
 * compiles at import). Before that, or for any other q, or a q the kernel refuses
 * (another length, NaN, a zero quaternion), it returns None: the caller's checked path
 * then answers or says what is wrong. The arithmetic is all in the numba kernels.
 *
 * Optional: when no C compiler is at hand the package installs without it, and chain.py
 * falls back to calling numba's compiled entry from Python.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <stdint.h>

/* kernel(chain, len(chain), q, len(q), out) -> 1 if it wrote out, 0 if it refused q */
typedef uint8_t (*kernel_t)(double *, int64_t, double *, int64_t, double *);
static kernel_t pose_kernel = NULL, poses_kernel = NULL;

static PyObject *bind(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "bind(pose_address, poses_address) takes two cfunc addresses");
        return NULL;
    }
    void *pose = PyLong_AsVoidPtr(args[0]);
    if (PyErr_Occurred()) return NULL;
    void *poses = PyLong_AsVoidPtr(args[1]);
    if (PyErr_Occurred()) return NULL;
    if (pose == NULL || poses == NULL) {
        PyErr_SetString(PyExc_ValueError, "bind() takes the addresses of two cfuncs, not 0");
        return NULL;
    }
    pose_kernel = (kernel_t)pose;
    poses_kernel = (kernel_t)poses;
    Py_RETURN_NONE;
}

/* 1 if the arguments are (chain, q) with a chain as chain.py makes it; else 0 with a TypeError set */
static int is_call(PyObject *const *args, Py_ssize_t nargs) {
    if (nargs == 2 && PyArray_CheckExact(args[0])) {
        PyArrayObject *chain = (PyArrayObject *)args[0];
        if (PyArray_TYPE(chain) == NPY_DOUBLE && PyArray_NDIM(chain) == 1 && PyArray_ISCARRAY_RO(chain) &&
            PyArray_DIM(chain, 0) >= 4)
            return 1;
    }
    PyErr_SetString(PyExc_TypeError, "takes (chain, q): a chain from mjkin.kinematics.chain.chain_of and a q");
    return 0;
}

/* the kernel's output (nd dims) for (chain, q), or None when q is not for it */
static PyObject *call(kernel_t kernel, PyObject *const *args, int nd, npy_intp *dims) {
    if (kernel == NULL) /* not bound yet (chain.ready() binds it on the first one-q pose): the checked path */
        Py_RETURN_NONE;
    PyArrayObject *chain = (PyArrayObject *)args[0], *q = (PyArrayObject *)args[1];
    if (!PyArray_CheckExact(args[1]) || PyArray_TYPE(q) != NPY_DOUBLE || PyArray_NDIM(q) != 1 ||
        !PyArray_ISCARRAY_RO(q))
        Py_RETURN_NONE;
    PyObject *out = PyArray_SimpleNew(nd, dims, NPY_DOUBLE);
    if (out == NULL) return NULL;
    if (!kernel((double *)PyArray_DATA(chain), PyArray_DIM(chain, 0), (double *)PyArray_DATA(q), PyArray_DIM(q, 0),
                (double *)PyArray_DATA((PyArrayObject *)out))) {
        Py_DECREF(out);
        Py_RETURN_NONE;
    }
    return out;
}

static PyObject *pose(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    npy_intp dims[2] = {4, 4};
    return is_call(args, nargs) ? call(pose_kernel, args, 2, dims) : NULL;
}

static PyObject *poses(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!is_call(args, nargs)) return NULL;
    /* the chain's body count n: its second header integer, stored bit for bit in a float64 */
    npy_intp dims[3] = {(npy_intp)((int64_t *)PyArray_DATA((PyArrayObject *)args[0]))[1], 4, 4};
    return call(poses_kernel, args, 3, dims);
}

static PyMethodDef methods[] = {
    {"bind", (PyCFunction)(void (*)(void))bind, METH_FASTCALL, "bind(pose_address, poses_address): the kernels."},
    {"pose", (PyCFunction)(void (*)(void))pose, METH_FASTCALL, "pose(chain, q): the chain's frame (4, 4), or None."},
    {"poses", (PyCFunction)(void (*)(void))poses, METH_FASTCALL, "poses(chain, q): each body's (n, 4, 4), or None."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_posecall", "One-q poses without numba's dispatch.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__posecall(void) {
    import_array();
    return PyModule_Create(&module);
}
