# Toolchain file for the STM32F411 (Cortex-M4F): arm-none-eabi-gcc, hard float, newlib nano, -Os.
#   cmake -S firmware -B build-fw -G Ninja -DCMAKE_TOOLCHAIN_FILE=cmake/arm-none-eabi.cmake
set(CMAKE_SYSTEM_NAME Generic)
set(CMAKE_SYSTEM_PROCESSOR arm)

find_program(ARM_NONE_EABI_GCC arm-none-eabi-gcc REQUIRED)
get_filename_component(_arm_bin "${ARM_NONE_EABI_GCC}" DIRECTORY)
set(CMAKE_C_COMPILER "${ARM_NONE_EABI_GCC}")
set(CMAKE_ASM_COMPILER "${ARM_NONE_EABI_GCC}")
find_program(CMAKE_SIZE arm-none-eabi-size HINTS "${_arm_bin}")
find_program(CMAKE_OBJCOPY arm-none-eabi-objcopy HINTS "${_arm_bin}")

# No host executables can run: test compiles build a static library.
set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY)

set(_mcu_flags "-mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16")
set(CMAKE_C_FLAGS_INIT "${_mcu_flags} -ffunction-sections -fdata-sections -fno-common -fno-math-errno")
set(CMAKE_ASM_FLAGS_INIT "${_mcu_flags}")
set(CMAKE_EXE_LINKER_FLAGS_INIT "${_mcu_flags} -specs=nano.specs -Wl,--gc-sections")
set(CMAKE_C_FLAGS_MINSIZEREL_INIT "-Os -DNDEBUG")
set(CMAKE_C_FLAGS_RELEASE_INIT "-Os -DNDEBUG")

set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
