//! Every budget the images are held to, in one place, each with the reason
//! it is what it is. The cycle harness (`src/bin/budget/main.rs`), the tests
//! (`tests/tests/image.rs`, `tests/tests/qemu.rs`), `./test.sh` (the image
//! as flashed) and the book (`tools/claims.py` reads this file: each
//! constant is the figure `budget_<name in lower case>`) take them from
//! here. A change that outgrows a budget shrinks the image, or moves the
//! budget in a commit of its own that says why.
//!
//! The chip: the STM32F405's 1 MiB of flash (sectors 0–3 of 16 KiB, 4 of
//! 64 KiB, 5–11 of 128 KiB) and 128 KiB of SRAM (plus 64 KiB of CCM, which
//! no DMA reaches). Cycle figures are QEMU instruction counts at an
//! assumed CPI of 1.5 with a 1.5 margin (only silicon can confirm the CPI).

/// `firmware` (our framed protocol), flash: 288 KiB of the 1 MiB, so that
/// the first 384 KiB (sectors 0–5) hold the image with room for MAVLink
/// signing (SHA-256, a few KiB) and leave sectors 6–11 (768 KiB) free.
pub const FIRMWARE_FLASH_BYTES: u32 = 288 * 1024;
/// `firmware`, static RAM: 22 KiB, the flight loop and its controller
/// (≈ 7 KiB), the estimator, the queues; the stack's 32 KiB and a parameter
/// store's page buffer (≤ 4 KiB) must still fit beside it in the SRAM.
pub const FIRMWARE_STATIC_RAM_BYTES: u32 = 22 * 1024;
/// `firmware-mavlink`, flash: 400 KiB, the MAVLink dialect's messages
/// included, with MAVLink signing (SHA-256 and the signing state), the
/// settings store that keeps the parameters and the key (≈ 22 KiB), and
/// each sensor's health with PX4's failure injection (fc-mavlink's
/// `sensor-faults`, ≈ 7.5 KiB: a vehicle that flies on its own sensors
/// must find the one that lies, on the board as in the SIL; it was
/// 392 KiB, without them, until issue 72), well below the settings' own
/// sectors 9–11 (from 640 KiB).
pub const MAVLINK_FLASH_BYTES: u32 = 400 * 1024;
/// `firmware-mavlink`, static RAM: 23 KiB, as `firmware`'s, less the
/// RTIC queues it does without, the settings' 2 KiB RAM stand-in in the
/// QEMU build, and the sensors' health and injected faults (≈ 0.4 KiB;
/// 22 KiB without them, until issue 72).
pub const MAVLINK_STATIC_RAM_BYTES: u32 = 23 * 1024;
/// `firmware-crtp`, flash: 392 KiB, with cflib's persistent parameters
/// (the settings store, `sequential-storage`'s map, ≈ 20 KiB of code),
/// well below the settings' own sectors 9–11 (`flash::STORAGE`, from
/// 640 KiB).
pub const CRTP_FLASH_BYTES: u32 = 392 * 1024;
/// `firmware-crtp`, static RAM: 36 KiB (the CRTP TOCs, the planner and the
/// syslink queues over `firmware`'s, 26 KiB, the settings' 2 KiB RAM
/// stand-in, `flash::STAND_IN_BYTES`, and the high-level commander's
/// trajectory memory, 4 KiB as the Crazyflie's `TRAJECTORY_MEMORY_SIZE`,
/// with its definitions: issue 70; it was 28 KiB until then).
pub const CRTP_STATIC_RAM_BYTES: u32 = 36 * 1024;
/// `firmware-crazyflie` built for QEMU, flash: 392 KiB, as `firmware-crtp`'s.
pub const CRAZYFLIE_FLASH_BYTES: u32 = 392 * 1024;
/// `firmware-crazyflie` built for QEMU, static RAM: 36 KiB, as `firmware-crtp`'s.
pub const CRAZYFLIE_STATIC_RAM_BYTES: u32 = 36 * 1024;
/// `firmware-crazyflie` as flashed (its own sensors, defmt over RTT),
/// flash: 408 KiB of the 624 KiB between Bitcraze's 16 KiB bootloader and
/// the settings' sectors 9–11: the QEMU build's, its drivers, and the
/// flash driver that keeps the settings (the store's code built for it).
pub const CRAZYFLIE_AS_FLASHED_FLASH_BYTES: u32 = 408 * 1024;
/// `firmware-crazyflie` as flashed, static RAM: 36 KiB (RTT's buffers,
/// 2.5 KiB, over the QEMU build's, less the RAM stand-in: the settings are
/// in the flash), as the QEMU build's.
pub const CRAZYFLIE_AS_FLASHED_STATIC_RAM_BYTES: u32 = 36 * 1024;

/// The whole image step of the fast MPC at 1 kHz (the IMU sample and a
/// fix in, the estimator, the MPC, the output), instructions: one 1 kHz
/// period of the 168 MHz STM32F405, 168 000 cycles, ÷ CPI 1.5 ÷ margin 1.5.
pub const IMAGE_STEP_INSTRUCTIONS: u32 = 74_600;
/// One estimator step (predict and a whole fix), instructions: the IMU
/// task's share of the 1 kHz step, leaving the controller's task the rest
/// of [`IMAGE_STEP_INSTRUCTIONS`].
pub const ESTIMATOR_STEP_INSTRUCTIONS: u32 = 20_000;
/// The longest the link's task may hold the vehicle for one radio packet
/// or one log poll, instructions. The vehicle's lock has the sample task's
/// priority: a sample that comes ready as a hold begins waits for it, then
/// takes its step, and both must fit the period of
/// [`IMAGE_STEP_INSTRUCTIONS`]: 6 000 is 8 % of it, and leaves the step
/// 68 600.
pub const LINK_HOLD_INSTRUCTIONS: u32 = 6_000;
/// Stack for designing and flying any controller, bytes: a quarter of the
/// SRAM (the controllers are designed in place, in static RAM).
pub const STACK_BYTES: u32 = 32 * 1024;
/// Stack of a whole image, every task's frames nested as their priorities
/// let them pre-empt (each image paints its stack at boot and logs the
/// high-water marks, `stack::Watch`), bytes: the SRAM less
/// the largest static RAM budget above (28 KiB), 100 KiB, with the cycle
/// budgets' margin of 1.5, rounded down to 64 KiB. flip-link puts the
/// stack below the statics, so an overflow faults rather than overwrites.
pub const IMAGE_STACK_BYTES: u32 = 64 * 1024;
/// Our QP step against tinympc-rs's on the same chip: at least this many
/// times fewer instructions, mean and worst (a budget, since QEMU's counts
/// are deterministic; what it measures is in the book).
pub const PEER_MIN_RATIO: u32 = 3;
