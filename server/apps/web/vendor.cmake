# Copies the page (SRC/src) and the JavaScript it imports from SRC/node_modules (installed by
# deploy/setup.sh from SRC/package-lock.json) into DST.
set(modules ${SRC}/node_modules)
foreach(f three/build/three.module.js three/build/three.core.js
          three/examples/jsm/controls/OrbitControls.js uplot/dist/uPlot.esm.js
          uplot/dist/uPlot.min.css)
  if(NOT EXISTS ${modules}/${f})
    message(FATAL_ERROR "telehand-web: ${modules}/${f} is missing: run deploy/setup.sh "
                        "(it installs the page's dependencies from web/package-lock.json)")
  endif()
endforeach()
file(REMOVE_RECURSE ${DST})
file(COPY ${SRC}/src/ DESTINATION ${DST})
file(COPY ${modules}/three/build/three.module.js ${modules}/three/build/three.core.js
          ${modules}/three/LICENSE DESTINATION ${DST}/vendor/three)
file(COPY ${modules}/three/examples/jsm/controls/OrbitControls.js
     DESTINATION ${DST}/vendor/three/addons)
file(COPY ${modules}/uplot/dist/uPlot.esm.js ${modules}/uplot/dist/uPlot.min.css
          ${modules}/uplot/LICENSE DESTINATION ${DST}/vendor/uplot)
file(WRITE ${DST}/.vendored "")
