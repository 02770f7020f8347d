// SPDX-License-Identifier: GPL-3.0-or-later
/*
 * The library's own global operator new and delete, all twenty replaceable
 * forms, for the macOS package (compiled only there: CMakeLists.txt, APPLE
 * branch of SPIA_PACKAGE).
 *
 * A macOS library cross-built with Zig links Zig's libc++ statically, and
 * libc++ defines these operators with default visibility: linked as they
 * are, the library would export them, and a host process (Blender) could
 * have the library's allocations and frees resolved against another
 * image's operators, or the other way round.  Zig's Mach-O linker ignores
 * -exported_symbols_list, so the linker cannot hide them; this file is
 * compiled with -fvisibility=hidden -fvisibility-global-new-delete=force-hidden,
 * which makes these definitions hidden, and being in an object file of the
 * library they are taken before libc++'s archive member.
 *
 * They behave as the standard's ([new.delete]): the throwing forms call the
 * new-handler while there is one and throw std::bad_alloc when there is
 * none; the nothrow forms return nullptr instead of throwing; a size of 0
 * gives a unique pointer; delete of nullptr does nothing.  Memory comes
 * from the C library: malloc and free, aligned_alloc (macOS 10.15 and
 * newer; the package's floor is 11.0) for the aligned forms, with the size
 * rounded up to a multiple of the alignment as C11 asks.
 */
#include <cstddef>
#include <cstdlib>
#include <new>

namespace {

void *allocate(std::size_t size) {
    if (size == 0)
        size = 1;
    for (;;) {
        if (void *p = std::malloc(size))
            return p;
        std::new_handler handler = std::get_new_handler();
        if (!handler)
            return nullptr;
        handler();  // may throw std::bad_alloc, which then leaves the operator
    }
}

void *allocate_aligned(std::size_t size, std::align_val_t alignment) {
    std::size_t align = static_cast<std::size_t>(alignment);
    if (align < sizeof(void *))
        align = sizeof(void *);
    if (size == 0)
        size = 1;
    if (size > static_cast<std::size_t>(-1) - align)
        return nullptr;
    size = (size + align - 1) & ~(align - 1);
    for (;;) {
        if (void *p = std::aligned_alloc(align, size))
            return p;
        std::new_handler handler = std::get_new_handler();
        if (!handler)
            return nullptr;
        handler();
    }
}

// The new-handler may throw (std::bad_alloc): allocate() lets it through,
// as the standard asks of the throwing forms; the nothrow forms catch it.
void *allocate_or_throw(std::size_t size) {
    void *p = allocate(size);
    if (!p)
        throw std::bad_alloc();
    return p;
}

void *allocate_aligned_or_throw(std::size_t size, std::align_val_t alignment) {
    void *p = allocate_aligned(size, alignment);
    if (!p)
        throw std::bad_alloc();
    return p;
}

}  // namespace

#define SPIA_NEW_TRY(expr) \
    try {                  \
        return expr;       \
    } catch (...) {        \
        return nullptr;    \
    }

void *operator new(std::size_t size) { return allocate_or_throw(size); }
void *operator new[](std::size_t size) { return allocate_or_throw(size); }
void *operator new(std::size_t size, std::align_val_t alignment) { return allocate_aligned_or_throw(size, alignment); }
void *operator new[](std::size_t size, std::align_val_t alignment) {
    return allocate_aligned_or_throw(size, alignment);
}
void *operator new(std::size_t size, const std::nothrow_t &) noexcept { SPIA_NEW_TRY(allocate_or_throw(size)) }
void *operator new[](std::size_t size, const std::nothrow_t &) noexcept { SPIA_NEW_TRY(allocate_or_throw(size)) }
void *operator new(std::size_t size, std::align_val_t alignment, const std::nothrow_t &) noexcept {
    SPIA_NEW_TRY(allocate_aligned_or_throw(size, alignment))
}
void *operator new[](std::size_t size, std::align_val_t alignment, const std::nothrow_t &) noexcept {
    SPIA_NEW_TRY(allocate_aligned_or_throw(size, alignment))
}

void operator delete(void *p) noexcept { std::free(p); }
void operator delete[](void *p) noexcept { std::free(p); }
void operator delete(void *p, std::size_t) noexcept { std::free(p); }
void operator delete[](void *p, std::size_t) noexcept { std::free(p); }
void operator delete(void *p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void *p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void *p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void *p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete(void *p, const std::nothrow_t &) noexcept { std::free(p); }
void operator delete[](void *p, const std::nothrow_t &) noexcept { std::free(p); }
void operator delete(void *p, std::align_val_t, const std::nothrow_t &) noexcept { std::free(p); }
void operator delete[](void *p, std::align_val_t, const std::nothrow_t &) noexcept { std::free(p); }
