(function(){
  const es = new EventSource('/events');
  es.addEventListener('runs', ev => { document.getElementById('runs').innerHTML = ev.data; });
})();
