#include "tests/support/scene_text.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstddef>

namespace fg::test {

int lineOf(const std::string& text, const std::string& marker) {
    const auto at = text.find(marker);
    if (at == std::string::npos) {
        ADD_FAILURE() << "'" << marker << "' is not in the text";
        return -1;
    }
    return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n'));
}

std::string mitsubaSceneText(const std::string& body, const MitsubaSceneOptions& options) {
    std::string sensor = options.sensor;
    if (sensor.empty()) {
        const std::string size = std::to_string(options.filmSize);
        sensor = "    <sensor type=\"perspective\">\n";
        if (options.fov) {
            // Mitsuba writes the value as given; integral values keep the files short.
            const double fov = *options.fov;
            const std::string value = fov == static_cast<double>(static_cast<long>(fov)) ? std::to_string(static_cast<long>(fov))
                                                                                           : std::to_string(fov);
            sensor += "        <float name=\"fov\" value=\"" + value + "\"/>\n";
        }
        sensor += "        <film type=\"hdrfilm\"><integer name=\"width\" value=\"" + size +
                  "\"/><integer name=\"height\" value=\"" + size + "\"/></film>\n    </sensor>\n";
    }
    return "<scene version=\"" + options.version + "\">\n" + sensor + body + "</scene>\n";
}

}  // namespace fg::test
