//! Every pin the Crazyflie 2.1 image uses, from the official firmware's
//! sources (`motors_def.c`, `led.h`, `i2c_drv.c`, `uart_syslink.c`,
//! `sensors_bmi088_bmp3xx.c`). Documentation and tests read this table; the
//! drivers take their pins from it.

/// A GPIO port.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Port {
    /// GPIOA.
    A,
    /// GPIOB.
    B,
    /// GPIOC.
    C,
    /// GPIOD.
    D,
}

/// One pin and what it is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pin {
    /// Port.
    pub port: Port,
    /// Pin number, 0–15.
    pub pin: u8,
    /// Alternate function number (0 for plain GPIO or EXTI).
    pub af: u8,
    /// What it does.
    pub role: &'static str,
}

const fn p(port: Port, pin: u8, af: u8, role: &'static str) -> Pin {
    Pin { port, pin, af, role }
}

/// The board's pins.
pub const PINS: [Pin; 15] = [
    p(Port::A, 1, 1, "M1 (TIM2_CH2)"),
    p(Port::B, 11, 1, "M2 (TIM2_CH4)"),
    p(Port::A, 15, 1, "M3 (TIM2_CH1)"),
    p(Port::B, 9, 2, "M4 (TIM4_CH4)"),
    p(Port::A, 8, 4, "I2C3 SCL (BMI088, BMP388), 400 kHz"),
    p(Port::C, 9, 4, "I2C3 SDA"),
    p(Port::C, 14, 0, "BMI088 gyroscope INT3, data ready (EXTI14, rising)"),
    p(Port::C, 6, 8, "USART6 TX to the nRF51 (syslink, 1 Mbaud)"),
    p(Port::C, 7, 8, "USART6 RX from the nRF51"),
    p(Port::A, 4, 0, "nRF51 flow control (TXEN)"),
    p(Port::C, 0, 0, "LED red left (active low)"),
    p(Port::C, 1, 0, "LED green left (active low)"),
    p(Port::C, 2, 0, "LED green right (active low)"),
    p(Port::C, 3, 0, "LED red right (active low)"),
    p(Port::D, 2, 0, "LED blue left (active high)"),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_pin_is_used_twice() {
        for (i, a) in PINS.iter().enumerate() {
            assert!(a.pin < 16);
            for b in &PINS[i + 1..] {
                assert!((a.port, a.pin) != (b.port, b.pin), "{} and {}", a.role, b.role);
            }
        }
    }
}
